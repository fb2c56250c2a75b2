"""Issue 28: one checked path resolver, pixel and array caps, atomic saves, one PLY reader,
wrapped errors and size estimates. Each test states the invariant it checks; each failed on
the main branch before the change (see the report of the hardening branch)."""
from __future__ import annotations

import json
import os
import signal
import sys

import numpy as np
import pytest
from _helpers import benchmark_module, peak_bytes
from PIL import Image

from geofit.io import load_mesh, load_obj, load_views


def _png(path, shape=(4, 6, 4), value=200):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full(shape, value, np.uint8)).save(path)
    return path


def _capture(root, frames):
    root.mkdir(parents=True, exist_ok=True)
    (root / "transforms.json").write_text(json.dumps(
        {"camera_angle_x": 0.7, "frames": [{"transform_matrix": np.eye(4).tolist(), **f}
                                           for f in frames]}))
    return root


# --------------------------------------------------------------------------- 1. path resolver
def test_extensionless_file_path_symlink_escape_refused(tmp_path):
    """``"file_path": "lnk"`` with ``lnk.png -> outside``: the extension candidate goes through
    the same check as the written path, so the outside file is never read."""
    secret = _png(tmp_path / "secret" / "s.png")
    cap = _capture(tmp_path / "cap", [{"file_path": "lnk"}])
    (cap / "lnk.png").symlink_to(secret)
    with pytest.raises(ValueError, match=r"frames\[0\]\.file_path: path 'lnk\.png' resolves "
                                         r"outside the capture folder"):
        load_views(cap)
    assert load_views(cap, allow_outside=True).images.shape == (1, 4, 6, 3)


def test_mask_path_symlink_escape_refused(tmp_path):
    """``mask_path`` goes through the resolver too (with and without an extension)."""
    secret = _png(tmp_path / "secret" / "m.png", (4, 6), 255)
    cap = _capture(tmp_path / "cap", [{"file_path": "a.png", "mask_path": "m"}])
    _png(cap / "a.png")
    (cap / "m.png").symlink_to(secret)
    with pytest.raises(ValueError, match=r"frames\[0\]\.mask_path: path 'm\.png' resolves "
                                         r"outside"):
        load_views(cap)


def test_fifo_and_folder_candidates_refused_without_opening(tmp_path):
    """A FIFO named by a capture or an MTL is refused from its file type (opening it would
    block forever); so is a folder."""
    cap = _capture(tmp_path / "cap", [{"file_path": "f"}])
    os.mkfifo(cap / "f.png")
    with pytest.raises(ValueError, match=r"file_path: .*f\.png' is a FIFO"):
        load_views(cap)
    (tmp_path / "m").mkdir()
    os.mkfifo(tmp_path / "m" / "t.png")
    (tmp_path / "m" / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    (tmp_path / "m" / "m.obj").write_text("mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                          "vt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(ValueError, match=r"m\.mtl: line 2: map_Kd texture: .*is a FIFO"):
        load_obj(tmp_path / "m" / "m.obj")
    os.mkfifo(tmp_path / "user.obj")
    with pytest.raises(ValueError, match=r"user\.obj: expected a regular OBJ file, got a FIFO"):
        load_obj(tmp_path / "user.obj")


def test_trimesh_resolver_refuses_what_the_policy_refuses(tmp_path):
    """The trimesh route's resolver is a ``trimesh.resolvers.Resolver`` with the same policy."""
    import trimesh

    from geofit.io._paths import PathPolicy, trimesh_resolver

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "ok.bin").write_bytes(b"abc")
    (tmp_path / "out.bin").write_bytes(b"secret")
    (tmp_path / "in" / "lnk.bin").symlink_to(tmp_path / "out.bin")
    r = trimesh_resolver(PathPolicy(tmp_path / "in"), "scene.gltf")
    assert isinstance(r, trimesh.resolvers.Resolver)
    assert r.get("ok.bin") == b"abc"
    for bad, why in (("../out.bin", "leaves"), ("lnk.bin", "resolves outside"),
                     (str(tmp_path / "out.bin"), "absolute"), ("x" * 5000, "too long")):
        with pytest.raises(ValueError, match=why):
            r.get(bad)


# ------------------------------------------------------------------------- 2. pixel and array caps
@pytest.fixture(scope="module")
def bomb_png(tmp_path_factory):
    """A ~140 KB PNG declaring 12000 x 12000 pixels."""
    p = tmp_path_factory.mktemp("bomb") / "bomb.png"
    Image.new("L", (12000, 12000)).save(p, optimize=True)
    assert p.stat().st_size < 300_000
    return p


def _glb(json_doc: dict, binary: bytes = b"") -> bytes:
    """A GLB container of a glTF document and its binary chunk (the loader fuzz's builder)."""
    return benchmark_module("fuzz_loaders").glb_container(json_doc, binary)


def _glb_with_image(image: bytes) -> bytes:
    doc = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": len(image)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(image)}],
           "images": [{"bufferView": 0, "mimeType": "image/png"}]}
    return _glb(doc, image)


def test_capture_image_pixel_bomb_refused_from_header(tmp_path, bomb_png):
    """A capture image declaring 144 M pixels is refused from its header (small peak memory);
    ``max_pixels=`` lowers or raises the cap."""
    cap = _capture(tmp_path / "cap", [{"file_path": "bomb.png"}])
    (cap / "bomb.png").write_bytes(bomb_png.read_bytes())
    err, peak = peak_bytes(load_views, cap)
    assert isinstance(err, ValueError) and "12000x12000" in str(err) and "cap" in str(err), err
    assert peak < 50 * 2**20
    _png(tmp_path / "small" / "a.png", (40, 50, 3))
    small = _capture(tmp_path / "small", [{"file_path": "a.png"}])
    with pytest.raises(ValueError, match=r"a\.png.*50x40 = 2,000 pixels, over the decoded-"
                                         r"pixel cap of 1,999"):
        load_views(small, max_pixels=1999)
    assert load_views(small, max_pixels=2000).images.shape == (1, 40, 50, 3)


def test_glb_image_pixel_bomb_refused_before_trimesh(tmp_path, bomb_png):
    """An image inside a GLB is checked from its header before trimesh decodes it."""
    p = tmp_path / "bomb.glb"
    p.write_bytes(_glb_with_image(bomb_png.read_bytes()))
    err, peak = peak_bytes(load_mesh, p)
    assert isinstance(err, ValueError), err
    assert "bomb.glb: images[0]" in str(err) and "12000x12000" in str(err)
    assert peak < 50 * 2**20


def test_obj_texture_pixel_cap_and_argument_checked(tmp_path):
    """``max_pixels`` is validated and applies to OBJ textures."""
    _png(tmp_path / "t.png", (30, 30, 3))
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    obj = tmp_path / "m.obj"
    obj.write_text("mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                   "f 1/1 2/2 3/3\n")
    with pytest.raises(ValueError, match=r"t\.png: the image is 30x30 = 900 pixels, over"):
        load_obj(obj, max_pixels=899)
    assert load_obj(obj, max_pixels=900).texture_images["a"].shape == (30, 30, 3)
    with pytest.raises(TypeError, match="max_pixels: expected None or a positive integer"):
        load_obj(obj, max_pixels="16")
    with pytest.raises(ValueError, match="max_pixels: expected None or a positive integer"):
        load_obj(obj, max_pixels=0)


def test_npz_compression_bomb_refused_from_header(tmp_path):
    """A small .npz whose array decodes to 240 MB (ratio ~1000) is refused from the .npy header,
    before inflating; the absolute cap ``max_bytes`` applies to any array."""
    import zipfile

    from geofit.io import load_pointcloud

    p = tmp_path / "bomb.npz"
    n = 10_000_000
    header = {"descr": "<f8", "fortran_order": False, "shape": (n, 3)}
    with zipfile.ZipFile(p, "w", compression=zipfile.ZIP_DEFLATED) as z:
        with z.open("verts.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(fh, header)
            zeros = bytes(8 << 20)
            for _ in range(n * 24 // len(zeros)):
                fh.write(zeros)
            fh.write(bytes(n * 24 % len(zeros)))
    assert p.stat().st_size < 1_000_000
    err, peak = peak_bytes(load_pointcloud, p)
    assert isinstance(err, ValueError) and "bomb.npz: array 'verts'" in str(err), err
    assert "240,000,000 bytes" in str(err) and "ratio" in str(err)
    assert peak < 50 * 2**20
    q = tmp_path / "small.npz"
    np.savez_compressed(q, verts=np.zeros((1000, 3)))
    assert len(load_pointcloud(q).points) == 1000
    with pytest.raises(ValueError, match=r"small\.npz: array 'verts'.*24,000 bytes, over the "
                                         r"cap of 23,999"):
        load_pointcloud(q, max_bytes=23_999)


# --------------------------------------------------------------------------- 3. atomic saves
def test_kill_during_save_and_disk_full_every_format():
    """For OBJ, PLY, STL, OFF, GLB, .npz/.ply clouds, JSON and a capture: a child killed at
    each of the 8 steps of a save leaves the old file or the complete new one; a save over a
    file-size limit (RLIMIT_FSIZE, a full disk) raises OSError and leaves the old file."""
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(root / "benchmarks" / "save_crash.py")],
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(root)})
    out = json.loads(proc.stdout)
    assert set(out["formats"]) >= {"obj", "ply", "stl", "off", "glb", "cloud_npz",
                                   "cloud_ply", "json"}
    assert len(out["kill_points"]) == 8
    for name, row in out["formats"].items():
        for point in out["kill_points"]:
            assert row[point] in ("old", "new"), (name, point, row[point])
        assert row["disk_full"] == "raised OSError; old file intact", (name, row)
    assert out["failures"] == 0 and proc.returncode == 0


def test_failed_write_removes_the_temporary_file_and_keeps_the_old(tmp_path, monkeypatch):
    """A writer that fails (or Open3D returning False) raises; no temporary file is left and
    the old content stays."""
    import open3d as o3d

    from geofit import PointCloud, ico_sphere
    from geofit._atomic import atomic_write
    from geofit.io import save_mesh, save_pointcloud

    target = tmp_path / "a.txt"
    target.write_text("old")

    def boom(tmp):
        tmp.write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match=r"a\.txt: could not write the file \(No space left"):
        atomic_write(target, boom)
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["a.txt"]
    save_mesh(tmp_path / "m.ply", ico_sphere(0))
    before = (tmp_path / "m.ply").read_bytes()
    monkeypatch.setattr(o3d.io, "write_triangle_mesh", lambda *a, **k: False)
    with pytest.raises(OSError, match=r"m\.ply: Open3D could not write the file"):
        save_mesh(tmp_path / "m.ply", ico_sphere(1))
    assert (tmp_path / "m.ply").read_bytes() == before
    def short(path, *args, **kwargs):  # Open3D after a full disk: a header, no data, True
        with open(path, "wb") as fh:
            fh.write(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n"
                     b"property double x\nend_header\n")
        return True

    monkeypatch.setattr(o3d.io, "write_point_cloud", short)
    with pytest.raises(OSError, match=r"short write"):  # True after a short write: caught
        save_pointcloud(tmp_path / "c.ply", PointCloud(np.zeros((9, 3))))
    assert not (tmp_path / "c.ply").exists()
    assert sorted(os.listdir(tmp_path)) == ["a.txt", "m.ply"]


# --------------------------------------------------------------------------- 4. one PLY reader
_PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
             "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
             "element face {nf}\nproperty list uchar int vertex_indices\nend_header\n")


@pytest.mark.parametrize("body, match", [
    ("0 0 0 300 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n3 0 1 2\n",
     r"PLY property 'red' is declared u1 but holds values that are not integers in \[0, 255\]"),
    ("0 0 0 -5 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n3 0 1 2\n", r"PLY property 'red' is declared"),
    ("0 0 0 1 2\n1 0 0 0 0 0\n0 1 0 0 0 0\n3 0 1 2\n", r"PLY vertex 0: expected 6 values per "
                                                       r"vertex line, got 5"),
])
def test_ascii_ply_out_of_range_or_short_lines_refused(tmp_path, body, match):
    """An ASCII PLY colour of 300 or -5 (uchar) and a vertex line with too few fields are
    refused by the one PLY reader, for meshes and clouds alike (trimesh wrapped them)."""
    from geofit.io import load_pointcloud

    p = tmp_path / "c.ply"
    p.write_text(_PLY_HEAD.format(nf=1) + body)
    with pytest.raises(ValueError, match=r"c\.ply: " + match):
        load_mesh(p)
    with pytest.raises(ValueError, match=r"c\.ply: " + match):
        load_pointcloud(p)


def test_ply_face_count_and_face_lines_checked(tmp_path):
    """``element face 999999999999`` with 2 face lines, a face line whose count disagrees with
    its indices, and an index out of range are refused; polygons are fan-triangulated."""
    verts = "0 0 0 0 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n"
    p = tmp_path / "f.ply"
    p.write_text(_PLY_HEAD.format(nf=999999999999) + verts + "3 0 1 2\n3 0 2 1\n")
    with pytest.raises(ValueError, match=r"f\.ply: the PLY header declares 999999999999 faces "
                                         r"but the file has fewer lines"):
        load_mesh(p)
    p.write_text(_PLY_HEAD.format(nf=1) + verts + "1000000000 0 1 2\n")
    with pytest.raises(ValueError, match=r"f\.ply: PLY face 0: expected a vertex count"):
        load_mesh(p)
    p.write_text(_PLY_HEAD.format(nf=1) + verts + "3 0 1 3\n")
    with pytest.raises(ValueError, match=r"f\.ply: PLY face index 3 is out of range"):
        load_mesh(p)
    p.write_text(_PLY_HEAD.replace("vertex 3", "vertex 4").format(nf=1) + verts
                 + "1 1 0 255 255 255\n4 0 1 3 2\n")
    m = load_mesh(p)
    np.testing.assert_array_equal(m.faces, [[0, 1, 3], [0, 3, 2]])
    np.testing.assert_allclose(m.textures.verts_features[3], [1.0, 1.0, 1.0])


def test_binary_ply_declared_faces_beyond_the_file_refused(tmp_path):
    """A binary PLY declaring more faces than its bytes hold is refused (not loaded short)."""
    from geofit import ico_sphere
    from geofit.io import save_mesh

    p = tmp_path / "b.ply"
    save_mesh(p, ico_sphere(1))
    data = p.read_bytes().replace(b"element face 80", b"element face 99")
    p.write_bytes(data)
    with pytest.raises(ValueError, match=r"b\.ply: the PLY header declares 99 faces"):
        load_mesh(p)


@pytest.mark.parametrize("body, match", [
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n1000000000 0 1 2\n", r"OFF face 0 declares 1000000000 "
                                                            r"corners but its line holds 3"),
    ("OFF\n3 999999999999 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
     r"the OFF header declares 3 vertices and 999999999999 faces"),
    ("OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n", r"OFF vertex 1 has 2 values"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", r"OFF face index 7 is out of range"),
])
def test_off_counts_checked(tmp_path, body, match):
    """OFF header counts and face-vertex counts are checked against the lines."""
    p = tmp_path / "o.off"
    p.write_text(body)
    with pytest.raises(ValueError, match=r"o\.off: " + match):
        load_mesh(p)
    p.write_text("OFF\n# a comment\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3 255 0 0\n")
    assert load_mesh(p).n_faces == 2


# --------------------------------------------------------------------------- 5. wrapped errors
def _glb_triangle(indices_accessor_count=3, index=0):
    """A GLB with one triangle; the index buffer holds ``index`` as its first index."""
    import struct

    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    idx = struct.pack("<III", index, 1, 2)
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
           "buffers": [{"byteLength": len(pos) + len(idx)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                           {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]},
                         {"bufferView": 1, "componentType": 5125,
                          "count": indices_accessor_count, "type": "SCALAR"}]}
    return _glb(doc, pos + idx)


def test_glb_index_out_of_range_is_a_value_error(tmp_path):
    """A GLB index 0xFFFFFFFF (face index, accessor, mesh, node, scene, texture coordinate):
    ValueError naming the file, the field and the valid range (trimesh's IndexError before)."""
    p = tmp_path / "i.glb"
    p.write_bytes(_glb_triangle(index=0xFFFFFFFF))
    with pytest.raises(ValueError, match=r"i\.glb: "):
        load_mesh(p)
    p.write_bytes(_glb_triangle())
    assert load_mesh(p).n_faces == 1
    import struct

    data = bytearray(_glb_triangle())
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(bytes(data[20:20 + n]))
    for field, set_bad in (
            ("scene", lambda d: d.__setitem__("scene", 0xFFFFFFFF)),
            (r"meshes\[0\]\.primitives\[0\]\.indices",
             lambda d: d["meshes"][0]["primitives"][0].__setitem__("indices", 0xFFFFFFFF)),
            (r"meshes\[0\]\.primitives\[0\]\.attributes\.TEXCOORD_0",
             lambda d: d["meshes"][0]["primitives"][0]["attributes"].__setitem__(
                 "TEXCOORD_0", 0xFFFFFFFF)),
            (r"nodes\[0\]", lambda d: d["nodes"][0].__setitem__("children", [0xFFFFFFFF]))):
        bad = json.loads(json.dumps(doc))
        set_bad(bad)
        binary = bytes(data[20 + n + 8:])
        p.write_bytes(_glb(bad, binary))
        with pytest.raises(ValueError, match=rf"i\.glb: {field}.* 4294967295 is not an index"):
            load_mesh(p)


@pytest.mark.parametrize("text, match", [
    ("[" * 100_000 + "]" * 100_000, r"transforms\.json: cannot read JSON"),
    ('{"frames": [{"file_path": "a.png", "fl_x": ' + "7" * 4400 + "}]}",
     r"transforms\.json: cannot read JSON"),
])
def test_deep_or_huge_json_is_a_value_error_naming_the_file(tmp_path, text, match):
    """transforms.json nested 100,000 deep (RecursionError before) or holding a 4,400-digit
    integer (json's ValueError without the file's name before)."""
    (tmp_path / "transforms.json").write_text(text)
    with pytest.raises(ValueError, match=match):
        load_views(tmp_path)


def test_very_long_file_path_is_a_value_error(tmp_path):
    """A 5,000-character ``file_path``: ValueError naming the field (OSError before)."""
    cap = _capture(tmp_path, [{"file_path": "a" * 5000}])
    with pytest.raises(ValueError, match=r"frames\[0\]\.file_path: the path .* is too long"):
        load_views(cap)


def test_glb_image_uri_naming_a_fifo_is_refused_without_blocking(tmp_path):
    """A GLB whose image URI names a FIFO is refused before anything opens it (trimesh blocked
    forever before); an alarm turns a regression into a failure instead of a hang."""
    os.mkfifo(tmp_path / "pipe.png")
    doc = {"asset": {"version": "2.0"}, "images": [{"uri": "pipe.png"}]}
    p = tmp_path / "f.glb"
    p.write_bytes(_glb(doc))
    old = signal.signal(signal.SIGALRM, lambda *a: (_ for _ in ()).throw(TimeoutError("hang")))
    signal.alarm(20)
    try:
        with pytest.raises(ValueError, match=r"f\.glb: images\[0\]\.uri: .*pipe\.png' is a "
                                             r"FIFO"):
            load_mesh(p)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# --------------------------------------------------------------------------- 6. size estimates
def _refused_at_once(fn, match):
    """``fn()`` raises ValueError (with the estimate) without allocating: small peak memory."""
    err, peak = peak_bytes(fn)
    assert isinstance(err, ValueError), err
    assert __import__("re").search(match, str(err)), str(err)
    assert "would need about" in str(err) and peak < 50 * 2**20


def test_counts_are_estimated_before_allocating(monkeypatch):
    """Samples, torus resolution, network width, faces per pixel and rays: refused at once with
    the estimate in the message (MemoryError after minutes before)."""
    from geofit import fit_mesh, ico_sphere
    from geofit.fit import MeshFitOptions
    from geofit.fit.nerf import NerfConfig
    from geofit.ops import sample_points_from_meshes
    from geofit.pytorch3d.renderer import RasterizationSettings as P3DSettings
    from geofit.render.soft import SoftRasterizationSettings
    from geofit.render.volume.raysampling import NDCMultinomialRaysampler
    from geofit.shapes import torus
    from geofit.cameras import FoVPerspectiveCameras

    monkeypatch.setenv("GEOFIT_MEMORY_LIMIT", "2G")
    m = ico_sphere(1)
    _refused_at_once(lambda: sample_points_from_meshes(m, 10**12), r"^num_samples: .* 182 TiB")
    _refused_at_once(lambda: torus(n_major=10**6, n_minor=10**6), r"^n_major and n_minor: ")
    _refused_at_once(lambda: NerfConfig(n_hidden_neurons=10**6).validate(),
                     r"^n_hidden_neurons: an MLP 1000000 wide")
    _refused_at_once(lambda: SoftRasterizationSettings(image_size=16, faces_per_pixel=10**9),
                     r"^image_size and faces_per_pixel: ")
    _refused_at_once(lambda: P3DSettings(image_size=16, blur_radius=1e-4,
                                         faces_per_pixel=10**9),
                     r"^image_size and faces_per_pixel: ")
    sampler = NDCMultinomialRaysampler(image_width=16, image_height=16, n_pts_per_ray=8,
                                       min_depth=0.1, max_depth=3.0, n_rays_per_image=10**12)
    _refused_at_once(lambda: sampler(FoVPerspectiveCameras()), r"^n_rays_per_image")
    _refused_at_once(lambda: fit_mesh(m, recipe="sphere",
                                      options=MeshFitOptions(n_samples=10**9)),
                     r"^options.n_samples: ")


def test_count_and_size_types_checked():
    """``image_size="16"`` (read as (1, 6) before) and a float count are refused naming the
    argument."""
    from geofit.ops import sample_points_from_meshes
    from geofit.pytorch3d.renderer import RasterizationSettings as P3DSettings
    from geofit.render import RasterizationSettings
    from geofit import ico_sphere

    with pytest.raises(ValueError, match=r"image_size: expected an int or \(H, W\), got str"):
        RasterizationSettings(image_size="16")
    with pytest.raises(ValueError, match=r"image_size: expected an int or \(H, W\), got str"):
        P3DSettings(image_size="16")
    with pytest.raises(ValueError, match=r"num_samples: expected an integer >= 1, got 10\.0"):
        sample_points_from_meshes(ico_sphere(0), 10.0)


def test_overflowing_target_says_so_not_zero_area():
    """``fit_mesh((verts * 1e300, faces))``: the message says the coordinates overflow."""
    from geofit import fit_mesh, ico_sphere

    m = ico_sphere(1)
    with pytest.raises(ValueError, match=r"target: coordinates up to 1e\+300 in absolute value "
                                         r"overflow areas and normals"):
        fit_mesh((m.verts * 1e300, m.faces))


# --------------------------------------------------------------------------- 8. the loader fuzz
def test_seeded_short_fuzz_run_has_no_escape_hang_blowup_or_unclear_error(tmp_path):
    """A seeded short run of benchmarks/fuzz_loaders.py over issue 28's targeted cases
    (symlinked extension-less paths, pixel and npz bombs, FIFOs, ASCII PLY ranges, OFF counts,
    deep JSON, long paths, glTF indices) and mutated PLY files: every input in a forked child
    with an audit hook on ``open``, peak memory and a timeout; all counts must be 0."""
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    data = os.environ.get("GEOFIT_DATA", "")
    if not (Path(data) / "cow_mesh" / "cow.obj").is_file():
        pytest.skip("GEOFIT_DATA with the tutorial files is needed for the fuzz inputs")
    out = tmp_path / "fuzz.json"
    proc = subprocess.run(
        [sys.executable, str(root / "benchmarks" / "fuzz_loaders.py"), "--n", "36",
         "--families", "targeted,ply", "--seed", "28", "--no-saves", "--timeout", "60",
         "--out", str(out)], capture_output=True, text=True, timeout=900,
        env={**os.environ, "PYTHONPATH": str(root)})
    assert out.is_file(), proc.stderr[-2000:]
    res = json.loads(out.read_text())
    assert res["config"]["n_inputs"] >= 30
    assert res["counts"]["targeted"].get("ValueError", 0) >= 10
    assert {k: v for k, v in res["issue28"].items() if v} == {}, res["examples_outside_allowed"]
    assert res["outside_allowed"] == 0 and proc.returncode == 0
