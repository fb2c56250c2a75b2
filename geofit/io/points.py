"""Point clouds on disk: ``.npz`` (PyTorch3D's PittsburghBridge layout) and ``.ply`` (Open3D)."""
from __future__ import annotations

import errno
import io
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .._atomic import atomic_write, write_bytes
from .._memory import check_allocation
from .._validate import as_array
from ._paths import check_input_file
from ..structures.pointcloud import PointCloud, as_pointcloud
from ._arrays import check_array_size, read_npy_header
from .obj import _tokens_per_line

__all__ = ["load_pointcloud", "save_pointcloud"]

_POINT_KEYS = ("verts", "points")
_COLOUR_KEYS = ("rgb", "colors", "colours", "features")
_MAX_COORD = 1e38  # larger coordinates overflow areas, normals and float32 rendering
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_COLOURS = (("red", "green", "blue"), ("r", "g", "b"),
                ("diffuse_red", "diffuse_green", "diffuse_blue"))
_HEADER_MAX = 1 << 16


def _colours_to_float(c: np.ndarray, path: Path, key: str) -> np.ndarray:
    if c.dtype.kind in "iu":
        if c.size and (c.min() < 0 or c.max() > 255):
            raise ValueError(f"{path}: integer colours {key!r} must lie in [0, 255], got range "
                             f"[{c.min()}, {c.max()}]")
        return c.astype(np.float64) / 255.0
    if c.dtype.kind == "b":
        return c.astype(np.float64)
    return c


# --------------------------------------------------------------------------- PLY
def _ply_header(path: Path, head: bytes):
    """Parse a PLY header -> (format, [(element, count, [(prop, dtype or (count, item))])], size)."""
    if not head.startswith(b"ply") or head[3:4] not in (b"\n", b"\r"):
        raise ValueError(f"{path}: not a PLY file (it does not start with a 'ply' line)")
    end = head.find(b"end_header")
    if end < 0:
        raise ValueError(f"{path}: PLY header without 'end_header' in its first "
                         f"{_HEADER_MAX // 1024} KiB (truncated or not a PLY file)")
    nl = head.find(b"\n", end)
    if nl < 0 or head[end + 10:nl].strip(b"\r \t"):
        raise ValueError(f"{path}: PLY header: 'end_header' must end its line")
    try:
        text = head[:end].decode("ascii")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: PLY header has non-ASCII bytes") from None
    fmt = None
    elements: list = []
    for ln, line in enumerate(text.replace("\r", "").split("\n")[1:], 2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) != 3 or tok[2] != "1.0" or tok[1] not in (
                    "ascii", "binary_little_endian", "binary_big_endian"):
                raise ValueError(f"{path}: PLY header line {ln}: unsupported format line")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit() or not tok[2].isascii():
                raise ValueError(f"{path}: PLY header line {ln}: expected 'element <name> "
                                 f"<count>' with a non-negative integer count")
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise ValueError(f"{path}: PLY header line {ln}: property before any element")
            props = elements[-1][2]
            if len(tok) == 3 and tok[1] in _PLY_TYPES:
                props.append((tok[2], _PLY_TYPES[tok[1]]))
            elif (len(tok) == 5 and tok[1] == "list" and tok[2] in _PLY_TYPES
                  and tok[3] in _PLY_TYPES and _PLY_TYPES[tok[2]][0] in "iu"):
                props.append((tok[4], (_PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]])))
            else:
                raise ValueError(f"{path}: PLY header line {ln}: unsupported property line")
        else:
            raise ValueError(f"{path}: PLY header line {ln}: unknown keyword {tok[0][:20]!r}")
    if fmt is None:
        raise ValueError(f"{path}: PLY header has no format line")
    return fmt, elements, nl + 1


def verify_binary_ply(path: Path, list_len: int = 3) -> None:
    """Raise OSError when a binary PLY just written is shorter or longer than its header says
    (every list property holding ``list_len`` items, as Open3D writes triangles). Open3D
    reports success after a short write (a full disk): this is the check."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_MAX)
    try:
        fmt, elements, body_start = _ply_header(path, head)
    except ValueError as exc:
        raise OSError(errno.EIO, f"{path}: the written PLY header is incomplete ({exc})") from None
    need = body_start
    for _, cnt, props in elements:  # a loop over the (two) elements
        row = 0
        for p in props:
            if isinstance(p[1], str):
                row += np.dtype(p[1]).itemsize
            else:
                row += np.dtype(p[1][0]).itemsize + list_len * np.dtype(p[1][1]).itemsize
        need += cnt * row
    if fmt != "ascii" and size != need:
        raise OSError(errno.EIO, f"{path}: short write: {size} bytes written, the PLY header "
                                 f"declares {need}")


def _read_ply(path: Path, limit):
    """Read the vertex element of a PLY file -> (points, colours or None, normals or None).

    Sizes declared by the header are checked against the file size before anything is
    allocated; the data is parsed with numpy (binary) or a vectorised text parse (ASCII).
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_MAX)
    fmt, elements, body_start = _ply_header(path, head)
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise ValueError(f"{path}: the PLY header declares no 'vertex' element")
    k = names.index("vertex")
    _, n, props = elements[k]
    pnames = [p[0] for p in props]
    if any(not isinstance(p[1], str) for p in props):
        raise ValueError(f"{path}: PLY 'vertex' element with list properties is not supported")
    missing = [c for c in "xyz" if c not in pnames]
    if missing:
        raise ValueError(f"{path}: PLY 'vertex' element has no {'/'.join(missing)} property")
    body = size - body_start
    if fmt == "ascii":
        # every value takes at least 2 bytes (a digit and a separator)
        need = 2 * sum(cnt * len(pr) for _, cnt, pr in elements[:k + 1])
    else:
        if any(not isinstance(p[1], str) for e in elements[:k] for p in e[2]):
            raise ValueError(f"{path}: PLY elements with list properties before 'vertex' are "
                             f"not supported")
        need = sum(cnt * sum(np.dtype(p[1]).itemsize for p in pr)
                   for _, cnt, pr in elements[:k + 1])
    if need > body:
        raise ValueError(f"{path}: the PLY header declares {n} vertices (at least {need} bytes "
                         f"of {fmt} data) but the file holds only {max(body, 0)} bytes after the "
                         f"header (truncated file or wrong count)")
    n_out = 3 + 3 * ("nx" in pnames) + 3 * any(c[0] in pnames for c in _PLY_COLOURS)
    per_value = 8 if fmt != "ascii" else 100  # ASCII: the line and token lists too
    check_allocation(n * (per_value * len(props) + 8 * n_out), setting=str(path),
                     what=f"the {n} declared vertices", limit=limit)
    if fmt == "ascii":
        data = _ply_ascii(path, elements, k, body_start)
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dt = np.dtype([(f"f{i}", order + p[1]) for i, p in enumerate(props)])
        offset = body_start + sum(cnt * sum(np.dtype(p[1]).itemsize for p in pr)
                                  for _, cnt, pr in elements[:k])
        with open(path, "rb") as fh:
            fh.seek(offset)
            raw = np.frombuffer(fh.read(n * dt.itemsize), dtype=dt, count=n)
        data = {p[0]: raw[f"f{i}"] for i, p in enumerate(props)}
    with np.errstate(invalid="ignore", over="ignore"):  # NaN / inf are refused by the caller
        pts = np.stack([data[c].astype(np.float64) for c in "xyz"], axis=1)
        nrm = (np.stack([data[c].astype(np.float64) for c in ("nx", "ny", "nz")], axis=1)
               if all(c in data for c in ("nx", "ny", "nz")) else None)
    col = None
    for cn in _PLY_COLOURS:
        if all(c in data for c in cn):
            col = np.stack([data[c] for c in cn], axis=1)
            if col.dtype.kind in "iu":  # 8-bit (or 16-bit) channels -> [0, 1]
                top = 255.0 if col.dtype.itemsize == 1 else float(np.iinfo(col.dtype).max)
                if col.min(initial=0) < 0:
                    raise ValueError(f"{path}: PLY colours must not be negative")
                col = col.astype(np.float64) / top
            else:
                col = col.astype(np.float64)
            break
    return pts, col, nrm


_PLURAL = {"vertex": "vertices", "face": "faces"}


def _ascii_rows(path: Path, elements: list, k: int, body_start: int, what: str) -> bytes:
    """The lines of ASCII PLY element ``k`` (one element per line, as the format's writers
    do), checked: as many lines as declared, only number characters."""
    with open(path, "rb") as fh:
        fh.seek(body_start)
        blob = fh.read()
    skip = sum(cnt for _, cnt, _ in elements[:k])
    n = elements[k][1]
    lines = blob.split(b"\n", skip + n)
    rows = lines[skip:skip + n]
    if len(rows) < n or (len(lines) == skip + n and not rows[-1].strip()):
        raise ValueError(f"{path}: the PLY header declares {n} {_PLURAL[what]} but the file has fewer "
                         f"lines (truncated file or wrong count)")
    text = b"\n".join(rows)
    arr = np.frombuffer(text, dtype=np.uint8)
    ok = _ASCII_OK[arr]
    if not ok.all():
        i = int(np.count_nonzero(arr[:int(np.flatnonzero(~ok)[0])] == 10))
        raise ValueError(f"{path}: PLY {what} {i}: unexpected character (only numbers and "
                         f"spaces are allowed in ASCII PLY data)")
    return text


def _ply_ascii(path: Path, elements: list, k: int, body_start: int) -> dict:
    """The vertex element of an ASCII PLY."""
    _, n, props = elements[k]
    text = _ascii_rows(path, elements, k, body_start, "vertex")
    counts = _tokens_per_line(np.frombuffer(text + b"\n", dtype=np.uint8))[2]
    if np.any(counts != len(props)):
        i = int(np.flatnonzero(counts != len(props))[0])
        raise ValueError(f"{path}: PLY vertex {i}: expected {len(props)} values per vertex "
                         f"line, got {int(counts[i])}")
    tokens = text.split()
    try:
        vals = np.array(tokens, dtype=np.float64).reshape(n, len(props))
    except ValueError:
        raise ValueError(f"{path}: PLY vertex data has a value that is not a number") from None
    data = {}
    for i, (name, typ) in enumerate(props):  # a loop over the few properties
        col = vals[:, i]
        if typ[0] in "iu":  # integer properties (colours): integral values in the type's range
            info = np.iinfo(typ)
            if not (np.all(col == np.round(col)) and np.all(col >= info.min)
                    and np.all(col <= info.max)):
                raise ValueError(f"{path}: PLY property {name!r} is declared {typ} but holds "
                                 f"values that are not integers in [{info.min}, {info.max}]")
            col = col.astype(typ)
        data[name] = col
    return data


_ASCII_OK = np.zeros(256, dtype=bool)
_ASCII_OK[[9, 10, 11, 12, 13, 32]] = True
_ASCII_OK[np.frombuffer(b"0123456789+-.eEnaifNAIFty", dtype=np.uint8)] = True


# --------------------------------------------------------------------------- NPZ
def _read_npz(path: Path, limit, max_bytes=None):
    """The arrays of a PittsburghBridge-style npz, sizes checked from the headers first."""
    with open(path, "rb") as fh:  # our handle: closed even when numpy fails half-way
        return _read_npz_from(path, fh, limit, max_bytes)


def _read_npz_from(path: Path, fh, limit, max_bytes=None):
    try:
        z = np.load(fh, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: expected an .npz archive, got a single .npy array")
    with z:
        keys = set(z.files)
        pk = next((k for k in _POINT_KEYS if k in keys), None)
        if pk is None:
            raise ValueError(f"{path}: expected the points under one of {_POINT_KEYS}, "
                             f"found keys {sorted(keys)[:20]}")
        ck = next((k for k in _COLOUR_KEYS if k in keys), None)
        wanted = [k for k in (pk, ck, "normals" if "normals" in keys else None) if k]
        total = 0
        for key in wanted:  # shapes and dtypes from the .npy headers, nothing decoded yet
            try:
                stored = z.zip.getinfo(key + ".npy").compress_size
                with z.zip.open(key + ".npy") as fh:
                    shape, _, dtype = read_npy_header(fh)
            except (ValueError, OSError, EOFError, KeyError, SyntaxError, TypeError,
                    zipfile.BadZipFile, zlib.error) as exc:
                raise ValueError(f"{path}: array {key!r} has an unreadable header "
                                 f"({type(exc).__name__})") from None
            if dtype.hasobject:
                raise ValueError(f"{path}: array {key!r} holds Python objects")
            check_array_size(shape, dtype, stored, f"{path}: array {key!r}", max_bytes)
            total += 2 * int(np.prod(shape, dtype=object)) * max(dtype.itemsize, 8)
        check_allocation(total, setting=str(path), what=f"the arrays {wanted}", limit=limit)
        try:
            pts = np.asarray(z[pk])
            col = None if ck is None else _colours_to_float(np.asarray(z[ck]), path, ck)
            nrm = np.asarray(z["normals"]) if "normals" in keys else None
        except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ValueError(f"{path}: array data is unreadable ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
    return pk, ck, pts, col, nrm


def load_pointcloud(path: str | os.PathLike, *, memory_limit=None,
                    max_bytes: int | None = None) -> PointCloud:
    """Read a point cloud with optional colours and normals.

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz``: the points under ``verts`` (PyTorch3D's PittsburghBridge file) or ``points``;
        colours, optional, under ``rgb``, ``colors``, ``colours`` or ``features``; normals,
        optional, under ``normals``.
        ``.ply``: ASCII or binary PLY; the ``vertex`` element's ``x, y, z``, optional
        ``nx, ny, nz`` and optional ``red, green, blue`` (or ``r, g, b``) properties.
    memory_limit : int or str, optional
        Bytes the decoded arrays may take (see :func:`geofit._memory.check_allocation`);
        default ``GEOFIT_MEMORY_LIMIT`` or half of the available memory.
    max_bytes : int, optional
        Most bytes one ``.npz`` array may decode to (default 1 GiB); arrays over 64 MiB must
        also decode to at most 100 times their compressed size (see :mod:`geofit.io._arrays`).

    Returns
    -------
    PointCloud
        ``points (k, 3) float64``; ``features (k, C) float64`` from the colours, or None;
        ``normals (k, 3) float64`` or None.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        Naming the file: an unsupported extension, an unreadable archive or header, a PLY
        shorter than its header declares, missing point key, wrong shapes, non-finite values or
        coordinates beyond 1e38, a colour count different from the point count, a file without
        points, or arrays whose decoded size exceeds the memory limit (checked before decoding).

    Notes
    -----
    Colour rule for ``.npz``: integer arrays (such as uint8) are 8-bit values and are divided
    by 255 (values outside [0, 255] are an error); float arrays are used as they are, assumed to
    be in [0, 1] already (the PittsburghBridge ``rgb`` array is read by the PyTorch3D tutorial
    as a float tensor and used directly as features). PLY colours stored as ``uchar`` are
    divided by 255 (``ushort`` by 65535), float colours are used as they are.
    The PLY reader parses the ``vertex`` element itself (numpy) rather than through Open3D,
    whose reader returns uninitialised points for a file shorter than its header.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".ply"):
        raise ValueError(f"path: expected a .npz or .ply file, got {path.name!r}")
    path = check_input_file(path, "point cloud file")
    try:
        if suffix == ".npz":
            pk, ck, pts, col, nrm = _read_npz(path, memory_limit, max_bytes)
        else:
            pts, col, nrm = _read_ply(path, memory_limit)
            pk, ck = "points", "colors"
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: unreadable file ({str(exc)[:200]})") from None
    except OSError as exc:  # permission denied, I/O errors
        raise ValueError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    except Exception as exc:  # noqa: BLE001 - zipfile and numpy raise NotImplementedError,
        # RuntimeError (encrypted entries), zlib.error, EOFError, ... for damaged archives
        raise ValueError(f"{path}: unreadable file ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    if pts.dtype.kind not in "biuf":
        raise ValueError(f"{path}: {pk}: expected a numeric array, got dtype {pts.dtype}")
    pts = as_array(pts, f"{path}: {pk}", (None, 3))
    if len(pts) == 0:
        raise ValueError(f"{path}: the file holds no points")
    if np.abs(pts).max() > _MAX_COORD:
        raise ValueError(f"{path}: {pk}: coordinates beyond {_MAX_COORD:g} in absolute value "
                         f"(max {np.abs(pts).max():.3g}); areas, distances and float32 "
                         f"rendering would overflow")
    if col is not None:
        if col.dtype.kind not in "biuf":
            raise ValueError(f"{path}: {ck}: expected a numeric array, got dtype {col.dtype}")
        if col.ndim == 1:
            col = col[:, None]
        col = as_array(col, f"{path}: {ck}", (len(pts), None))
    if nrm is not None:
        if nrm.dtype.kind not in "biuf":
            raise ValueError(f"{path}: normals: expected a numeric array, got dtype {nrm.dtype}")
        nrm = as_array(nrm, f"{path}: normals", (len(pts), 3))
    try:
        return PointCloud(pts, col, nrm)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def save_pointcloud(path: str | os.PathLike, cloud: PointCloud) -> None:
    """Write a point cloud as ``.npz`` or ``.ply``.

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz``: keys ``verts`` (k, 3) float64, ``rgb`` (k, C) float64 when the cloud has
        features, ``normals`` (k, 3) when it has normals (the PittsburghBridge layout); exact.
        ``.ply``: binary PLY through Open3D; positions and normals are written as doubles,
        colours as 8-bit values (so they come back quantised to multiples of 1/255); only the
        first three feature channels are written, and the features must then lie in [0, 1].
    cloud : PointCloud
        The cloud.

    Raises
    ------
    TypeError
        If ``cloud`` is not a PointCloud.
    ValueError
        For an unsupported extension, or features that a PLY cannot hold (fewer than three
        channels, values outside [0, 1]).
    """
    path = Path(path)
    cloud = as_pointcloud(cloud, "cloud")  # a geofit, trimesh or Open3D point cloud
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".ply"):
        raise ValueError(f"path: expected a .npz or .ply file, got {path.name!r}")
    if suffix == ".npz":
        arrays = {"verts": cloud.points}
        if cloud.features is not None:
            arrays["rgb"] = cloud.features
        if cloud.normals is not None:
            arrays["normals"] = cloud.normals
        buf = io.BytesIO()  # a file object keeps numpy from appending ".npz"
        np.savez_compressed(buf, **arrays)
        write_bytes(path, buf.getbuffer())
        return
    import open3d as o3d

    f = cloud.features
    if f is not None:
        if f.shape[1] < 3:
            raise ValueError(f"cloud.features: a PLY needs 3 colour channels, got {f.shape[1]}")
        if f.size and (f[:, :3].min() < 0 or f[:, :3].max() > 1):
            raise ValueError("cloud.features: PLY colours must lie in [0, 1], got range "
                             f"[{f[:, :3].min():.6g}, {f[:, :3].max():.6g}]")
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(cloud.points)))
    if f is not None:
        pc.colors = o3d.utility.Vector3dVector(np.array(f[:, :3]))
    if cloud.normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.array(cloud.normals))
    atomic_write(path, lambda tmp: _open3d_ok(
        o3d.io.write_point_cloud(str(tmp), pc, write_ascii=False), path),
        verify=verify_binary_ply)


def _open3d_ok(ok: bool, path: Path) -> None:
    """Open3D's writers return False on failure instead of raising."""
    if not ok:
        raise OSError(errno.EIO, f"{path}: Open3D could not write the file")


# --------------------------------------------------------------------------- PLY faces
class PlyLayoutNotRead(Exception):
    """A valid binary PLY layout this reader does not parse (polygons of mixed sizes, list
    properties before the faces): the caller reads it with trimesh and checks the counts."""


_FACE_LISTS = ("vertex_indices", "vertex_index")


def read_ply_mesh(path: Path, limit=None):
    """A PLY mesh -> (verts (V, 3), faces (F, 3) int64 or None, colours (V, C) or None).

    The one PLY reader (meshes and clouds): counts, sizes and integer ranges are checked
    against the header; polygons are fan-triangulated ``(v0, vi, vi+1)``. Raises
    :class:`PlyLayoutNotRead` for binary layouts it does not parse.
    """
    pts, col, _ = _read_ply(path, limit)
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_MAX)
    fmt, elements, body_start = _ply_header(path, head)
    names = [e[0] for e in elements]
    if "face" not in names or elements[names.index("face")][1] == 0:
        return pts, None, col
    j = names.index("face")
    _, m, props = elements[j]
    lists = [i for i, p in enumerate(props) if not isinstance(p[1], str)]
    if len(lists) != 1 or props[lists[0]][0] not in _FACE_LISTS:
        raise ValueError(f"{path}: PLY 'face' element: expected one list property "
                         f"'vertex_indices', got {[p[0] for p in props]}")
    li = lists[0]
    if fmt == "ascii":
        counts, flat = _ply_ascii_faces(path, elements, j, body_start, li)
    else:
        counts, flat = _ply_binary_faces(path, fmt, elements, j, body_start, li)
    if len(counts) != m:
        raise ValueError(f"{path}: the PLY header declares {m} faces, the file holds "
                         f"{len(counts)}")
    if counts.size and counts.min() < 3:
        i = int(np.flatnonzero(counts < 3)[0])
        raise ValueError(f"{path}: PLY face {i} has {int(counts[i])} vertices (at least 3)")
    n = len(pts)
    if flat.size and (flat.min() < 0 or flat.max() >= n):
        bad = int(flat[(flat < 0) | (flat >= n)][0])
        raise ValueError(f"{path}: PLY face index {bad} is out of range for {n} vertices")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_tri = counts - 2
    tri_face = np.repeat(np.arange(m), n_tri)
    local = np.arange(len(tri_face)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    base = starts[tri_face]
    faces = flat[np.stack([base, base + local, base + local + 1], axis=1)]
    return pts, faces.astype(np.int64), col


def _ply_ascii_faces(path: Path, elements: list, j: int, body_start: int, li: int):
    """(corner counts (m,), flat indices) of the ASCII face element ``j``: every line holds
    its declared count of indices plus the element's other properties, all integers."""
    props = elements[j][2]
    text = _ascii_rows(path, elements, j, body_start, "face")
    ntok = _tokens_per_line(np.frombuffer(text + b"\n", dtype=np.uint8))[2]
    try:
        vals = np.array(text.split(), dtype=np.float64)
    except ValueError:
        raise ValueError(f"{path}: PLY face data has a value that is not a number") from None
    line_start = np.concatenate([[0], np.cumsum(ntok)[:-1]])
    before = li  # scalar properties before the list (rare): their values come first
    has = ntok > before
    counts = np.where(has, vals[np.minimum(line_start + before, len(vals) - 1)], -1)
    n_scalar = len(props) - 1
    bad = ~has | (counts != np.round(counts)) | (counts < 0) | (ntok != 1 + counts + n_scalar)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{path}: PLY face {i}: expected a vertex count followed by that many "
                         f"indices ({n_scalar} other value(s)), got {int(ntok[i])} values")
    counts = counts.astype(np.int64)
    first = np.repeat(line_start + before + 1, counts)
    pos = first + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    flat = vals[pos]
    if flat.size and (np.any(flat != np.round(flat)) or np.abs(flat).max() > 2**62):
        raise ValueError(f"{path}: PLY face indices must be integers")
    return counts, flat.astype(np.int64)


def _ply_binary_faces(path: Path, fmt: str, elements: list, j: int, body_start: int, li: int):
    """(corner counts, flat indices) of the binary face element ``j`` when every face has the
    same corner count (triangles, quads); else :class:`PlyLayoutNotRead`."""
    order = "<" if fmt == "binary_little_endian" else ">"
    for _, _, pr in elements[:j]:
        if any(not isinstance(p[1], str) for p in pr):
            raise PlyLayoutNotRead("list properties before the faces")
    offset = body_start + sum(cnt * sum(np.dtype(p[1]).itemsize for p in pr)
                              for _, cnt, pr in elements[:j])
    _, m, props = elements[j]
    size = path.stat().st_size
    ctype, itype = props[li][1]
    pre = sum(np.dtype(p[1]).itemsize for p in props[:li])
    with open(path, "rb") as fh:
        fh.seek(offset + pre)
        first = fh.read(np.dtype(ctype).itemsize)
    if len(first) < np.dtype(ctype).itemsize:
        raise ValueError(f"{path}: the PLY header declares {m} faces but the file ends before "
                         f"them (truncated file or wrong count)")
    c = int(np.frombuffer(first, dtype=order + ctype)[0])
    fields = [(f"p{i}", order + p[1]) for i, p in enumerate(props[:li])]
    fields += [("n", order + ctype), ("idx", order + itype, (max(c, 0),))]
    fields += [(f"q{i}", order + p[1]) for i, p in enumerate(props[li + 1:])]
    dt = np.dtype(fields)
    if offset + m * dt.itemsize > size:
        raise ValueError(f"{path}: the PLY header declares {m} faces ({m * dt.itemsize} bytes) "
                         f"but the file holds only {size - offset} bytes for them (truncated "
                         f"file or wrong count)")
    with open(path, "rb") as fh:
        fh.seek(offset)
        raw = np.frombuffer(fh.read(m * dt.itemsize), dtype=dt, count=m)
    if np.any(raw["n"] != c):
        raise PlyLayoutNotRead("faces of mixed sizes")
    return np.full(m, c, dtype=np.int64), raw["idx"].astype(np.int64).ravel()


def ply_declared_counts(path: Path) -> dict:
    """``{element: count}`` from a PLY header (for checking another reader's result)."""
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_MAX)
    return {e[0]: e[1] for e in _ply_header(path, head)[1]}
