"""Checks of a GLB / glTF file before trimesh reads it (issue 28 points 1, 2 and 5).

trimesh decodes every image of a glTF scene with PIL and opens every URI the file names. Before
it runs, :func:`check_gltf` reads the JSON (nesting and number sizes wrapped as ValueError
naming the file), checks that every buffer view and image lies inside its buffer, sends every
URI through the path policy (a FIFO or an outside file is refused before anything opens it) and
checks every image's pixel count from its header against the cap.
"""
from __future__ import annotations

import base64
import binascii
import struct
from pathlib import Path

from ._images import check_image_bytes
from ._jsonread import parse_json
from ._paths import PathPolicy

__all__ = ["check_gltf"]

_GLB_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A
_BIN_CHUNK = 0x004E4942
_MAX_DEPTH = 64


def _depth_ok(obj, limit: int) -> bool:
    stack = [(obj, 0)]
    while stack:  # a loop over the JSON nodes (few: a glTF's JSON is small)
        o, d = stack.pop()
        if d > limit:
            return False
        if isinstance(o, dict):
            stack.extend((v, d + 1) for v in o.values())
        elif isinstance(o, list):
            stack.extend((v, d + 1) for v in o)
    return True


def _glb_chunks(data: bytes, where: str):
    """(JSON bytes, BIN bytes or None) of a binary glTF."""
    if len(data) < 20:
        raise ValueError(f"{where}: GLB file of {len(data)} bytes is shorter than its header")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != _GLB_MAGIC or version != 2:
        raise ValueError(f"{where}: expected a GLB version 2 header, got magic {magic!r} "
                         f"version {version}")
    if length > len(data):
        raise ValueError(f"{where}: the GLB header declares {length} bytes, the file has "
                         f"{len(data)} (truncated)")
    chunks, off = [], 12
    while off + 8 <= length:  # a loop over the (two) chunks
        clen, ctype = struct.unpack_from("<II", data, off)
        if off + 8 + clen > length:
            raise ValueError(f"{where}: GLB chunk at byte {off} declares {clen} bytes, past "
                             f"the end of the file")
        chunks.append((ctype, data[off + 8:off + 8 + clen]))
        off += 8 + clen
    if not chunks or chunks[0][0] != _JSON_CHUNK:
        raise ValueError(f"{where}: the first GLB chunk is not JSON")
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _BIN_CHUNK else None
    return chunks[0][1], binary


def _index(value, n: int, what: str, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < n:
        raise ValueError(f"{where}: {what} {value!r:.40} is not an index in [0, {n})")
    return value


def _nonneg(d: dict, key: str, where: str, default=None) -> int:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ValueError(f"{where}.{key}: expected a non-negative integer, got {v!r:.40}")
    return v


def check_gltf(data: bytes, path: Path, fmt: str, policy: PathPolicy, max_pixels) -> None:
    """Refuse (ValueError naming ``path``) a GLB/glTF whose JSON, buffer views, URIs or images
    break the rules in the module notes; return None when trimesh may read it."""
    where = str(path)
    if fmt == "GLB":
        text, binary = _glb_chunks(data, where)
    else:
        text, binary = data, None
    doc = parse_json(text, where)
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: expected a JSON object at the top level of the glTF, got "
                         f"{type(doc).__name__}")
    if not _depth_ok(doc, _MAX_DEPTH):
        raise ValueError(f"{where}: the glTF JSON is nested deeper than {_MAX_DEPTH} levels")
    lists = {}
    for key in ("buffers", "bufferViews", "images", "accessors", "meshes", "nodes", "scenes",
                "materials", "textures", "samplers"):
        v = doc.get(key, [])
        if not isinstance(v, list) or not all(isinstance(e, dict) for e in v):
            raise ValueError(f"{where}: {key}: expected a list of objects")
        lists[key] = v
    buffers = []
    for i, b in enumerate(lists["buffers"]):  # a loop over the (few) buffers
        w = f"{where}: buffers[{i}]"
        uri = b.get("uri")
        if uri is None:
            if binary is None:
                raise ValueError(f"{w}: no uri and no GLB binary chunk")
            buffers.append(binary)
        else:
            buffers.append(_uri_bytes(uri, w, policy))
        if _nonneg(b, "byteLength", w) > len(buffers[-1]):
            raise ValueError(f"{w}: byteLength {b['byteLength']} is more than the "
                             f"{len(buffers[-1])} bytes it holds")
    views = []
    for i, v in enumerate(lists["bufferViews"]):
        w = f"{where}: bufferViews[{i}]"
        buf = buffers[_index(v.get("buffer"), len(buffers), "buffer", w)]
        off, n = _nonneg(v, "byteOffset", w, 0), _nonneg(v, "byteLength", w)
        if off + n > len(buf):
            raise ValueError(f"{w}: bytes [{off}, {off + n}) lie outside its buffer of "
                             f"{len(buf)} bytes")
        views.append((buf, off, n))
    for i, a in enumerate(lists["accessors"]):
        if "bufferView" in a:
            _index(a["bufferView"], len(views), "bufferView", f"{where}: accessors[{i}]")
    _check_references(doc, lists, where)
    for i, im in enumerate(lists["images"]):  # a loop over the (few) images
        w = f"{where}: images[{i}]"
        if "bufferView" in im:
            buf, off, n = views[_index(im["bufferView"], len(views), "bufferView", w)]
            blob = buf[off:off + n]
        elif "uri" in im:
            blob = _uri_bytes(im["uri"], w, policy)
        else:
            raise ValueError(f"{w}: neither a bufferView nor a uri")
        check_image_bytes(blob, w, max_pixels)


def _check_references(doc: dict, lists: dict, where: str) -> None:
    """Every index a glTF object holds (scene, nodes, meshes, accessors, materials, textures)
    names an existing entry: a clear ValueError instead of trimesh's IndexError."""
    n = {k: len(v) for k, v in lists.items()}
    if "scene" in doc:
        _index(doc["scene"], n["scenes"], "scene", where)
    for i, sc in enumerate(lists["scenes"]):  # loops over the (few) JSON objects
        for c in _int_list(sc.get("nodes", []), f"{where}: scenes[{i}].nodes"):
            _index(c, n["nodes"], "node", f"{where}: scenes[{i}].nodes")
    for i, nd in enumerate(lists["nodes"]):
        w = f"{where}: nodes[{i}]"
        if "mesh" in nd:
            _index(nd["mesh"], n["meshes"], "mesh", w)
        for c in _int_list(nd.get("children", []), f"{w}.children"):
            _index(c, n["nodes"], "node", f"{w}.children")
    for i, me in enumerate(lists["meshes"]):
        prims = me.get("primitives", [])
        if not isinstance(prims, list) or not all(isinstance(p, dict) for p in prims):
            raise ValueError(f"{where}: meshes[{i}].primitives: expected a list of objects")
        for j, pr in enumerate(prims):
            w = f"{where}: meshes[{i}].primitives[{j}]"
            attrs = pr.get("attributes", {})
            if not isinstance(attrs, dict):
                raise ValueError(f"{w}.attributes: expected an object")
            for name, a in attrs.items():
                _index(a, n["accessors"], "accessor", f"{w}.attributes.{name}")
            if "indices" in pr:
                _index(pr["indices"], n["accessors"], "accessor", f"{w}.indices")
            if "material" in pr:
                _index(pr["material"], n["materials"], "material", f"{w}.material")
    for i, t in enumerate(lists["textures"]):
        if "source" in t:
            _index(t["source"], n["images"], "image", f"{where}: textures[{i}].source")
        if "sampler" in t:
            _index(t["sampler"], n["samplers"], "sampler", f"{where}: textures[{i}].sampler")
    for i, m in enumerate(lists["materials"]):
        for key, tex in _texture_refs(m):
            _index(tex, n["textures"], "texture", f"{where}: materials[{i}].{key}.index")


def _int_list(v, where: str) -> list:
    if not isinstance(v, list):
        raise ValueError(f"{where}: expected a list of indices")
    return v


def _texture_refs(material: dict):
    """(key, texture index) of the texture slots of a glTF material."""
    slots = [(k, material.get(k)) for k in ("normalTexture", "occlusionTexture",
                                            "emissiveTexture")]
    pbr = material.get("pbrMetallicRoughness")
    if isinstance(pbr, dict):
        slots += [(k, pbr.get(k)) for k in ("baseColorTexture", "metallicRoughnessTexture")]
    return [(k, t.get("index")) for k, t in slots if isinstance(t, dict)]


def _uri_bytes(uri, where: str, policy: PathPolicy) -> bytes:
    if not isinstance(uri, str):
        raise ValueError(f"{where}.uri: expected a string, got {type(uri).__name__}")
    if uri.startswith("data:"):
        head, _, payload = uri.partition(",")
        if not head.endswith(";base64"):
            raise ValueError(f"{where}.uri: only base64 data URIs are read")
        try:
            return base64.b64decode(payload, validate=True)
        except (binascii.Error, ValueError):
            raise ValueError(f"{where}.uri: the base64 data is malformed") from None
    from urllib.parse import unquote

    return policy.read_bytes(unquote(uri), f"{where}.uri")
