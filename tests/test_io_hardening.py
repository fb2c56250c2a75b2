"""Loaders under careless or hostile input: truncated files, huge headers, odd bytes, odd images.

Each test states the invariant: the loader returns the file's true values or raises
ValueError / FileNotFoundError naming the file, and checks sizes before it allocates.
"""
from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from _helpers import peak_bytes

from geofit import PointCloud
from geofit.io import load_mesh, load_obj, load_objs_as_meshes, load_pointcloud, save_pointcloud

TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
UV = "vt 0 0\nvt 1 0\nvt 0 1\n"


def write(path: Path, data) -> Path:
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(data)
    return path


PLY_HEAD = ("ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n")


# --------------------------------------------------------------------------- PLY
@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_shorter_than_header_raises_naming_file(tmp_path, fmt):
    """A header-only PLY declaring 3000 vertices: ValueError naming the file, no garbage points."""
    p = write(tmp_path / "short.ply", PLY_HEAD.format(fmt=fmt, n=3000).encode())
    with pytest.raises(ValueError, match=r"short\.ply: the PLY header declares 3000 vertices"):
        load_pointcloud(p)
    # two of three vertices present: still refused
    body = (b"1 2 3\n4 5 6\n" if fmt == "ascii" else
            np.arange(6, dtype="<f4" if "little" in fmt else ">f4").tobytes())
    p = write(tmp_path / "short2.ply", PLY_HEAD.format(fmt=fmt, n=3).encode() + body)
    with pytest.raises(ValueError, match=r"short2\.ply: .*3 vertices"):
        load_pointcloud(p)


def test_ply_huge_count_in_tiny_file_refused_before_allocating(tmp_path):
    """1e8 vertices declared in ~120 bytes: refused from the file size, peak memory tiny."""
    p = write(tmp_path / "huge.ply", PLY_HEAD.format(fmt="binary_little_endian",
                                                     n=100_000_000).encode())
    assert p.stat().st_size < 200
    err, peak = peak_bytes(load_pointcloud, p)
    assert isinstance(err, ValueError) and "huge.ply" in str(err)
    assert "100000000 vertices" in str(err)
    assert peak < 10 * 2**20


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_reads_exact_values(tmp_path, fmt):
    """Points, normals and 8-bit colours of a PLY come back exactly (colours / 255)."""
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(7, 3)).astype(np.float32)
    nrm = rng.normal(size=(7, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(7, 3)).astype(np.uint8)
    head = ("ply\nformat {} 1.0\ncomment test\nelement vertex 7\nproperty float x\n"
            "property float y\nproperty float z\nproperty float nx\nproperty float ny\n"
            "property float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            "element face 0\nproperty list uchar int vertex_indices\nend_header\n").format(fmt)
    if fmt == "ascii":
        body = "".join(" ".join([*map(repr, map(float, a)), *map(str, c)]) + "\n"
                       for a, c in zip(np.hstack([pts, nrm]), rgb)).encode()
    else:
        e = "<" if "little" in fmt else ">"
        dt = np.dtype([(f"f{i}", e + "f4") for i in range(6)] + [(f"c{i}", "u1") for i in range(3)])
        rec = np.zeros(7, dt)
        for i in range(6):
            rec[f"f{i}"] = np.hstack([pts, nrm])[:, i]
        for i in range(3):
            rec[f"c{i}"] = rgb[:, i]
        body = rec.tobytes()
    c = load_pointcloud(write(tmp_path / "v.ply", head.encode() + body))
    np.testing.assert_array_equal(c.points, pts.astype(np.float64))
    np.testing.assert_array_equal(c.normals, nrm.astype(np.float64))
    np.testing.assert_array_equal(c.features, rgb / 255.0)


@pytest.mark.parametrize(
    "body, match",
    [
        (b"1 2 3\n4 5\x1f6\n7 8 9\n", "unexpected character"),
        (b"1 2 3\n4 abc 6\n7 8 9\n", "unexpected character"),
        (b"1 2 3\n4 5 6 7\n8 9\n", "expected 3 values per vertex"),
        (b"1 2 3\n4 e 6\n7 8 9\n", "not a number"),
        (b"1 2 3\n4 nan 6\n7 8 9\n", "expected finite values"),
        (b"1 2 3\n4 1e154 6\n7 8 9\n", "coordinates beyond 1e\\+38"),
    ],
)
def test_ply_ascii_bad_values(tmp_path, body, match):
    """Control characters, words, wrong counts and non-finite values: ValueError, no shift."""
    p = write(tmp_path / "bad.ply", PLY_HEAD.format(fmt="ascii", n=3).encode() + body)
    with pytest.raises(ValueError, match=r"bad\.ply: .*" + match):
        load_pointcloud(p)


@pytest.mark.parametrize(
    "data, match",
    [
        (b"", "not a PLY file"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "without 'end_header'"),
        (b"ply\nformat ascii 2.0\nend_header\n", "unsupported format"),
        (b"ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", "non-negative integer"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
         "unsupported property"),
        (b"ply\nformat ascii 1.0\nelement face 1\nproperty float x\nend_header\n0\n",
         "no 'vertex' element"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n",
         "no y/z property"),
    ],
)
def test_ply_header_errors(tmp_path, data, match):
    with pytest.raises(ValueError, match=r"h\.ply: .*" + match):
        load_pointcloud(write(tmp_path / "h.ply", data))


def test_ply_written_by_open3d_round_trips(tmp_path):
    """Binary PLYs written by save_pointcloud (Open3D) are read back by geofit's own reader."""
    rng = np.random.default_rng(1)
    cloud = PointCloud(rng.normal(size=(50, 3)), rng.random((50, 3)), rng.normal(size=(50, 3)))
    save_pointcloud(tmp_path / "c.ply", cloud)
    c = load_pointcloud(tmp_path / "c.ply")
    np.testing.assert_array_equal(c.points, cloud.points)
    np.testing.assert_array_equal(c.normals, cloud.normals)
    np.testing.assert_allclose(c.features, cloud.features, atol=0.5 / 255 + 1e-12)


# --------------------------------------------------------------------------- NPZ
def _npz_with_header(path: Path, key: str, shape, payload: bytes = b"") -> Path:
    """An npz whose ``key`` entry declares ``shape`` (float64) but holds only ``payload``."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False,
                                               "shape": tuple(shape)})
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr(key + ".npy", buf.getvalue() + payload)
    return path


def test_npz_huge_arrays_refused_before_decoding(tmp_path, monkeypatch):
    """An npz whose header declares 3e9 floats: ValueError naming the file and limit, no decode."""
    monkeypatch.setenv("GEOFIT_MEMORY_LIMIT", "1G")
    p = _npz_with_header(tmp_path / "big.npz", "verts", (10**9, 3))
    err, peak = peak_bytes(load_pointcloud, p)
    assert isinstance(err, ValueError), err
    assert "big.npz" in str(err) and "24,000,000,000 bytes, over the cap" in str(err)
    err, peak = peak_bytes(load_pointcloud, p, max_bytes=10**12)  # then the ratio cap
    assert isinstance(err, ValueError) and "from 73 bytes in the file" in str(err), err
    assert peak < 10 * 2**20
    # a real (compressible) array over an explicit limit is refused the same way
    np.savez_compressed(tmp_path / "z.npz", verts=np.zeros((200_000, 3)))
    with pytest.raises(ValueError, match=r"z\.npz: the arrays \['verts'\] would need about"):
        load_pointcloud(tmp_path / "z.npz", memory_limit="1M")
    assert load_pointcloud(tmp_path / "z.npz", memory_limit="1G").points.shape == (200_000, 3)


def test_npz_damaged_files(tmp_path):
    """Not a zip, a zip holding garbage, a truncated entry, a bare .npy: ValueError naming it."""
    with pytest.raises(ValueError, match=r"a\.npz: not a readable \.npz"):
        load_pointcloud(write(tmp_path / "a.npz", b"garbage bytes"))
    with zipfile.ZipFile(tmp_path / "b.npz", "w") as z:
        z.writestr("verts.npy", b"not an npy")
    with pytest.raises(ValueError, match=r"b\.npz: array 'verts' has an unreadable header"):
        load_pointcloud(tmp_path / "b.npz")
    p = _npz_with_header(tmp_path / "c.npz", "verts", (4, 3), b"\0" * 40)
    with pytest.raises(ValueError, match=r"c\.npz: array data is unreadable"):
        load_pointcloud(p)
    with open(tmp_path / "d.npz", "wb") as fh:
        np.save(fh, np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"d\.npz: expected an \.npz archive"):
        load_pointcloud(tmp_path / "d.npz")
    raw = (tmp_path / "e.npz")
    np.savez_compressed(raw, verts=np.zeros((3, 3)))
    data = raw.read_bytes()
    write(raw, data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"e\.npz: "):
        load_pointcloud(raw)
    np.savez(tmp_path / "f.npz", verts=np.array([["a", "b", "c"]]))
    with pytest.raises(ValueError, match=r"f\.npz: verts: expected a numeric array"):
        load_pointcloud(tmp_path / "f.npz")
    np.savez(tmp_path / "g.npz", verts=np.array([[1e154, 0, 0]]))
    with pytest.raises(ValueError, match=r"g\.npz: verts: coordinates beyond 1e\+38"):
        load_pointcloud(tmp_path / "g.npz")


# --------------------------------------------------------------------------- OBJ text
def test_utf8_bom_keeps_first_line(tmp_path):
    """A UTF-8 byte-order mark before the first vertex (or the mtllib) is dropped, not the line."""
    p = write(tmp_path / "bom.obj", b"\xef\xbb\xbf" + (TRI + "f 1 2 3\n").encode())
    np.testing.assert_array_equal(load_obj(p).verts, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    write(tmp_path / "m.mtl", b"\xef\xbb\xbfnewmtl a\nKd 0.25 0.5 1\n")
    p = write(tmp_path / "bom2.obj",
              b"\xef\xbb\xbf" + ("mtllib m.mtl\nusemtl a\n" + TRI + "f 1 2 3\n").encode())
    d = load_obj(p)
    np.testing.assert_array_equal(d.materials["a"].Kd, [0.25, 0.5, 1.0])


@pytest.mark.parametrize("ch", ["\x1f", "\x1c", "\x00", "\x85", "\u2028", "\xa0", "\x7f"])
def test_control_characters_between_numbers_refused(tmp_path, ch):
    """A control, separator or non-ASCII character between numbers: ValueError with the line,
    never a coordinate taken from the next value or vertex."""
    p = write(tmp_path / "c.obj", f"v 0 0 0\nv 1 2{ch}3 4\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"c\.obj: line 2: vertex line has a control or "
                                         r"non-ASCII character"):
        load_obj(p)
    p = write(tmp_path / "t.obj", f"{TRI}vt 0 0{ch}1\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"t\.obj: line 4: texture coordinate line"):
        load_obj(p)
    p = write(tmp_path / "f.obj", f"{TRI}f 1 2{ch}3\n")
    with pytest.raises(ValueError, match=r"f\.obj: line 4: "):
        load_obj(p)


def test_line_endings_and_whitespace(tmp_path):
    """\\r\\n, lone \\r, tabs, form feeds and vertical tabs are line ends or spaces, consistently."""
    for text in (TRI.replace("\n", "\r\n") + "f 1 2 3\r\n", TRI.replace("\n", "\r") + "f 1 2 3",
                 "v 0\t0 0\nv 1\x0c0 0\nv 0 1\x0b0\nf 1 2 3\n"):
        d = load_obj(write(tmp_path / "e.obj", text))
        np.testing.assert_array_equal(d.verts, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
        np.testing.assert_array_equal(d.faces, [[0, 1, 2]])


def test_huge_coordinates_refused(tmp_path):
    """Coordinates near 1e154 would make areas and normals overflow: refused with the line."""
    p = write(tmp_path / "big.obj", "v 0 0 0\nv 1e154 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"big\.obj: line 2: vertex coordinate beyond 1e\+38"):
        load_obj(p)
    with pytest.raises(ValueError, match=r"big\.obj: line 2"):
        load_mesh(p)
    np.testing.assert_array_equal(
        load_obj(write(tmp_path / "ok.obj", "v 0 0 0\nv 1e30 0 0\nv 0 1 0\nf 1 2 3\n")).verts[1],
        [1e30, 0, 0])


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-5", "1e999"])
@pytest.mark.parametrize("key", ["Kd", "Ks", "Ka", "Ns"])
def test_mtl_non_finite_or_negative_refused(tmp_path, key, value):
    """MTL colours and the specular exponent must be finite and non-negative; the message names
    the MTL file, the line and the key, never the line's content."""
    write(tmp_path / "m.mtl", f"newmtl a\n{key} {value} 0.5 0.5\n" if key != "Ns"
          else f"newmtl a\nNs {value}\n")
    p = write(tmp_path / "m.obj", "mtllib m.mtl\nusemtl a\n" + TRI + "f 1 2 3\n")
    with pytest.raises(ValueError, match=rf"m\.mtl: line 2: {key} values must be finite and "
                                         r"non-negative$"):
        load_obj(p)


def test_unreadable_obj_is_value_error(tmp_path):
    """A directory named like an OBJ is refused as not a regular file; a bad PLY too."""
    (tmp_path / "d.obj").mkdir()
    with pytest.raises(ValueError, match=r"d\.obj: expected a regular OBJ file, got a folder"):
        load_obj(tmp_path / "d.obj")
    write(tmp_path / "bad.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nend_header\n")
    with pytest.raises(ValueError, match=r"bad\.ply: "):
        load_mesh(tmp_path / "bad.ply")


# --------------------------------------------------------------------------- textures
def _textured(tmp_path: Path, tex_name: str) -> Path:
    write(tmp_path / "m.mtl", f"newmtl a\nmap_Kd {tex_name}\n")
    return write(tmp_path / "m.obj", "mtllib m.mtl\nusemtl a\n" + TRI + UV + "f 1/1 2/2 3/3\n")


def test_16bit_png_keeps_its_values(tmp_path):
    """A 16-bit greyscale PNG texture is scaled by 65535, not clipped to white by convert("RGB")."""
    grey = np.array([[0, 1000], [30000, 65535]], dtype=np.uint16)
    Image.fromarray(grey).save(tmp_path / "t.png")
    d = load_obj(_textured(tmp_path, "t.png"))
    img = d.texture_images["a"]
    assert img.shape == (2, 2, 3)
    np.testing.assert_allclose(img, np.repeat(grey[:, :, None] / 65535.0, 3, axis=2), rtol=0,
                               atol=1e-15)


def test_float_tiff_keeps_its_values(tmp_path):
    """A float32 TIFF texture keeps its values (not truncated to black by convert("RGB"))."""
    a = np.array([[0.0, 0.125], [0.5, 0.9]], dtype=np.float32)
    Image.fromarray(a).save(tmp_path / "t.tif")
    img = load_obj(_textured(tmp_path, "t.tif")).texture_images["a"]
    np.testing.assert_array_equal(img, np.repeat(a.astype(np.float64)[:, :, None], 3, axis=2))
    Image.fromarray(np.array([[np.nan, 0]], dtype=np.float32)).save(tmp_path / "n.tif")
    with pytest.raises(ValueError, match=r"n\.tif: the float image has NaN"):
        load_obj(_textured(tmp_path, "n.tif"))


def test_8bit_textures_unchanged(tmp_path):
    """8-bit RGB, RGBA, palette and greyscale textures: PyTorch3D's convert("RGB") / 255."""
    rgb = np.arange(12, dtype=np.uint8).reshape(2, 2, 3) * 20
    for mode in ("RGB", "RGBA", "P", "L"):
        Image.fromarray(rgb).convert(mode).save(tmp_path / f"{mode}.png")
        img = load_obj(_textured(tmp_path, f"{mode}.png")).texture_images["a"]
        want = np.asarray(Image.fromarray(rgb).convert(mode).convert("RGB")) / 255.0
        np.testing.assert_array_equal(img, want)


@pytest.mark.parametrize(
    "data",
    [b"", b"not an image at all", b"\x89PNG\r\n\x1a\n" + b"\0" * 40, b"GIF89a\x01\x00",
     b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x02\x00\x00\x00\x02\x08\x02"],
)
def test_texture_not_an_image(tmp_path, data):
    """A texture that is not an image, or a damaged one: ValueError naming the texture file."""
    write(tmp_path / "t.png", data)
    with pytest.raises(ValueError, match=r"t\.png: not a readable image"):
        load_obj(_textured(tmp_path, "t.png"))
    with pytest.raises(ValueError, match=r"t\.png: not a readable image"):
        load_objs_as_meshes([tmp_path / "m.obj"])


def test_truncated_png_texture(tmp_path):
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)).save(tmp_path / "f.png")
    data = (tmp_path / "f.png").read_bytes()
    write(tmp_path / "t.png", data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"t\.png: not a readable image"):
        load_obj(_textured(tmp_path, "t.png"))


def test_png_bomb_refused_by_estimate_before_decoding(tmp_path, monkeypatch):
    """A ~100 KB PNG that decodes to 12000 x 12000 pixels (over 8 GB as float64 RGB): refused
    from its header size before decoding; the test's peak memory stays small."""
    p = tmp_path / "bomb.png"
    Image.new("L", (12000, 12000)).save(p, optimize=True)  # 144 MB while writing, not loading
    assert p.stat().st_size < 300_000
    monkeypatch.setenv("GEOFIT_MEMORY_LIMIT", "2G")
    obj = _textured(tmp_path, "bomb.png")
    err, peak = peak_bytes(load_obj, obj)
    assert isinstance(err, ValueError), err
    assert "bomb.png" in str(err) and "12000x12000" in str(err) and "pixel cap" in str(err)
    assert peak < 50 * 2**20
    # with the pixel cap raised, the memory estimate still refuses it before decoding
    err, peak = peak_bytes(load_obj, obj, max_pixels=10**9)
    assert isinstance(err, ValueError), err
    assert "bomb.png" in str(err) and "12000x12000" in str(err) and "memory limit" in str(err)
    assert peak < 50 * 2**20


# --------------------------------------------------------------------------- path policy
SECRET = "Kd secret line of an outside file\n"


@pytest.fixture
def outside(tmp_path):
    """A folder ``mesh/`` holding the OBJ, and files outside it (a texture and a 'secret')."""
    (tmp_path / "mesh").mkdir()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (4, 4, 3), dtype=np.uint8)).save(tmp_path / "out.png")
    write(tmp_path / "secret.txt", "newmtl a\n" + SECRET)
    return tmp_path


def _obj(folder: Path, mtllib: str) -> Path:
    return write(folder / "m.obj", f"mtllib {mtllib}\nusemtl a\n" + TRI + UV + "f 1/1 2/2 3/3\n")


@pytest.mark.parametrize("how", ["absolute", "dotdot", "symlink"])
def test_texture_path_outside_folder_refused(outside, how):
    """map_Kd naming a file outside the MTL's folder (absolute, ../, or a symlink pointing out)
    is refused with ValueError naming the MTL and line, and followed with allow_outside=True."""
    mesh = outside / "mesh"
    ref = {"absolute": str(outside / "out.png"), "dotdot": "../out.png", "symlink": "link.png"}[how]
    if how == "symlink":
        (mesh / "link.png").symlink_to(outside / "out.png")
    write(mesh / "m.mtl", f"newmtl a\nmap_Kd {ref}\n")
    p = _obj(mesh, "m.mtl")
    why = {"absolute": "absolute path .* refused", "dotdot": "path '../out.png' leaves the folder",
           "symlink": "path 'link.png' resolves outside the folder"}[how]
    with pytest.raises(ValueError, match=rf"m\.mtl: line 2: map_Kd texture: {why}.*"
                                         r"allow_outside=True"):
        load_obj(p)
    for loader in (load_objs_as_meshes, load_mesh):
        with pytest.raises(ValueError, match="allow_outside=True"):
            loader(p)
    want = np.asarray(Image.open(outside / "out.png")) / 255.0
    np.testing.assert_array_equal(load_obj(p, allow_outside=True).texture_images["a"], want)
    np.testing.assert_array_equal(load_mesh(p, allow_outside=True).textures.maps, want)
    assert load_objs_as_meshes([p], allow_outside=True)[0].textures is not None
    assert load_obj(p, load_textures=False).materials == {}  # nothing is read without textures


@pytest.mark.parametrize("how", ["absolute", "dotdot", "symlink"])
def test_mtllib_outside_folder_refused_without_echo(outside, how):
    """mtllib naming a file outside the OBJ's folder is refused before it is opened, so no line
    of it can appear in a message; with allow_outside=True its errors still do not echo it."""
    mesh = outside / "mesh"
    ref = {"absolute": str(outside / "secret.txt"), "dotdot": "../secret.txt",
           "symlink": "link.mtl"}[how]
    if how == "symlink":
        (mesh / "link.mtl").symlink_to(outside / "secret.txt")
    p = _obj(mesh, ref)
    with pytest.raises(ValueError, match=r"m\.obj: line 1: mtllib: (absolute )?path") as info:
        load_obj(p)
    assert "secret line" not in str(info.value)
    with pytest.raises(ValueError, match=r"line 2: Kd has a non-numeric value$") as info:
        load_obj(p, allow_outside=True)
    assert "secret line" not in str(info.value)


def test_paths_inside_folder_and_subfolders_allowed(outside):
    """Relative paths into the folder or its subfolders (also through a symlink that stays
    inside, and with Windows separators) are followed by default."""
    mesh = outside / "mesh"
    (mesh / "sub").mkdir()
    Image.fromarray(np.full((2, 2, 3), 128, np.uint8)).save(mesh / "sub" / "t.png")
    (mesh / "in.png").symlink_to(mesh / "sub" / "t.png")
    write(mesh / "sub" / "m.mtl", "newmtl a\nmap_Kd t.png\n")
    for ref in ("sub/m.mtl", "sub\\m.mtl", "./sub/../sub/m.mtl"):
        d = load_obj(_obj(mesh, ref))
        np.testing.assert_array_equal(d.texture_images["a"], np.full((2, 2, 3), 128 / 255))
    write(mesh / "m2.mtl", "newmtl a\nmap_Kd in.png\n")
    assert "a" in load_obj(_obj(mesh, "m2.mtl")).texture_images
    # a texture path resolving from the MTL's subfolder up into the OBJ's folder: outside the
    # MTL's own folder, so refused (the rule is the folder of the file that names it)
    write(mesh / "sub" / "up.mtl", "newmtl a\nmap_Kd ../in.png\n")
    with pytest.raises(ValueError, match=r"up\.mtl: line 2: .*leaves the folder"):
        load_obj(_obj(mesh, "sub/up.mtl"))


@pytest.mark.parametrize("allow_outside", [False, True])
def test_referenced_path_with_control_character(tmp_path, allow_outside):
    """A NUL or other control character in a map_Kd / mtllib path (found by the long fuzz run:
    'embedded null byte' named no file): ValueError naming the file and line."""
    write(tmp_path / "m.mtl", "newmtl a\nmap_Kd t\x00.png\n")
    p = _obj(tmp_path, "m.mtl")
    with pytest.raises(ValueError, match=r"m\.mtl: line 2: map_Kd texture: the path has a "
                                         r"control character"):
        load_obj(p, allow_outside=allow_outside)
    p = write(tmp_path / "n.obj", "mtllib m\x01.mtl\n" + TRI + "f 1 2 3\n")
    with pytest.raises(ValueError, match=r"n\.obj: line 1: mtllib: the path has a control"):
        load_obj(p, allow_outside=allow_outside)


def test_docstring_examples():
    """The Examples of geofit.io.obj run as doctests."""
    import doctest

    import geofit.io.obj

    result = doctest.testmod(geofit.io.obj)
    assert result.attempted >= 1 and result.failed == 0
