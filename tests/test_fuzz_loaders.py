"""Property-based fuzzing of every loader (hypothesis; small example counts here, the long run
is benchmarks/fuzz_loaders.py).

Invariant for any input: the loader returns a finite result whose indices are in range, or
raises ValueError / FileNotFoundError with a message naming a file. Any other exception type,
a warning other than geofit's documented missing-MTL UserWarning (e.g. a numpy overflow
RuntimeWarning), or a non-finite array fails the test.
"""
from __future__ import annotations

import io
import tempfile
import warnings
import zipfile
from pathlib import Path

import hypothesis.configuration
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from geofit import Mesh
from geofit.io import ObjData, load_mesh, load_obj, load_pointcloud

# hypothesis keeps caches in ./.hypothesis by default: keep them out of the working tree
hypothesis.configuration.set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "geofit-hypothesis")
FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def check_obj(d: ObjData) -> None:
    """A loaded OBJ is finite and its indices are in range."""
    assert np.isfinite(d.verts).all() and np.isfinite(d.normals).all()
    assert np.isfinite(d.verts_uvs).all()
    assert d.faces.min() >= 0 and d.faces.max() < len(d.verts)
    assert d.faces_uvs.min() >= -1 and d.faces_uvs.max() < max(len(d.verts_uvs), 1)
    assert d.faces_normals_idx.min() >= -1 and d.faces_normals_idx.max() < max(len(d.normals), 1)
    for img in d.texture_images.values():
        assert img.ndim == 3 and img.shape[2] == 3 and np.isfinite(img).all()


def check_mesh(m: Mesh) -> None:
    """Derived quantities of a loaded mesh are finite (no overflow that NaNs flow from)."""
    assert np.isfinite(m.verts).all()
    assert np.isfinite(m.face_areas).all() and np.isfinite(m.verts_normals).all()


def outcome(fn, *args, **kwargs):
    """Run a loader: its result, or None after an allowed error. Anything else propagates."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*material library not found",
                                category=UserWarning)
        try:
            return fn(*args, **kwargs)
        except (ValueError, FileNotFoundError) as exc:
            msg = str(exc)
            assert msg.strip(), f"{type(exc).__name__} without a message"
            assert "/" in msg or ".obj" in msg or ".ply" in msg or ".npz" in msg or \
                msg.startswith("path:"), f"the message names no file: {msg!r}"
            return None


# --------------------------------------------------------------------------- OBJ / MTL / texture
_NUM = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**20, 10**20).map(str),
    st.sampled_from(["nan", "inf", "-inf", "1e154", "1e400", "", "-", "+", "1e", ".", "0x10",
                     "1\x1f2", "١", "\xa0", "1,5"]),
)
_IDX = st.one_of(st.integers(-12, 12), st.integers(-10**19, 10**19)).map(str)
_CORNER = st.one_of(
    _IDX, st.tuples(_IDX, _IDX).map("/".join), st.tuples(_IDX, _IDX).map(lambda t: f"{t[0]}//{t[1]}"),
    st.tuples(_IDX, _IDX, _IDX).map("/".join), st.sampled_from(["/", "//", "1/", "a", "1/2/3/4"]))
_LINE = st.one_of(
    st.lists(_NUM, max_size=5).map(lambda t: "v " + " ".join(t)),
    st.lists(_NUM, max_size=4).map(lambda t: "vt " + " ".join(t)),
    st.lists(_NUM, max_size=4).map(lambda t: "vn " + " ".join(t)),
    st.lists(_CORNER, max_size=11).map(lambda t: "f " + " ".join(t)),
    st.sampled_from(["usemtl a", "usemtl b", "usemtl", "mtllib m.mtl", "mtllib ../m.mtl",
                     "mtllib /etc/passwd", "mtllib missing.mtl", "mtllib sub", "# comment", "",
                     "g group", "s off", "o name"]),
    st.text(max_size=30),
)
_VALID = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
_MTL_LINE = st.one_of(
    st.tuples(st.sampled_from(["Ka", "Kd", "Ks", "Ns"]), st.lists(_NUM, max_size=4)).map(
        lambda t: t[0] + " " + " ".join(t[1])),
    st.sampled_from(["newmtl a", "newmtl b", "newmtl", "map_Kd t.png", "map_Kd missing.png",
                     "map_Kd ../t.png", "map_Kd /etc/hostname", "map_Kd m.obj", "map_Kd sub",
                     "map_Kd -s 1 1 1 t.png", "map_Kd", "map_Kd t\x00.png"]),
    st.text(max_size=20),
)


def _png(rgb) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    return buf.getvalue()


_TEXTURE = st.one_of(
    st.binary(max_size=200),
    st.sampled_from(["rgb", "grey16", "float"]).map(
        lambda kind: {"rgb": lambda: _png(np.full((3, 4, 3), 7, np.uint8)),
                      "grey16": lambda: _png(np.full((3, 4), 40000, np.uint16)),
                      "float": lambda: _tiff(np.full((2, 2), 0.5, np.float32))}[kind]()),
    st.tuples(st.integers(0, 200), st.binary(min_size=1, max_size=8)).map(
        lambda t: _mutate(_png(np.arange(48, dtype=np.uint8).reshape(4, 4, 3)), *t)),
)


def _tiff(a) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="TIFF")
    return buf.getvalue()


def _mutate(data: bytes, pos: int, new: bytes) -> bytes:
    pos = pos % max(len(data), 1)
    return data[:pos] + new + data[pos + len(new):]


def _write_tree(root: Path, files: dict) -> None:
    for name, data in files.items():
        p = root / name
        if data is None:
            p.mkdir(exist_ok=True)
        elif isinstance(data, bytes):
            p.write_bytes(data)
        else:
            p.write_text(data, encoding="utf-8", errors="surrogatepass")


@FUZZ
@given(lines=st.lists(_LINE, max_size=25), prefix=st.sampled_from(["", _VALID, "\ufeff"]),
       crlf=st.booleans())
def test_fuzz_obj_text(lines, prefix, crlf):
    """Random OBJ lines (numbers, indices, control characters, k-gons, material statements)."""
    text = prefix + "\n".join(lines) + "\n"
    if crlf:
        text = text.replace("\n", "\r\n")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "mesh"
        root.mkdir()
        _write_tree(root, {"m.obj": text.encode("utf-8", "surrogatepass"),
                           "m.mtl": "newmtl a\nKd 1 1 1\n", "sub": None})
        d = outcome(load_obj, root / "m.obj")
        if d is not None:
            check_obj(d)
        m = outcome(load_mesh, root / "m.obj")
        if m is not None:
            check_mesh(m)


@FUZZ
@given(mtl=st.lists(_MTL_LINE, max_size=8), texture=_TEXTURE, with_texture=st.booleans(),
       allow_outside=st.booleans())
def test_fuzz_mtl_and_texture(mtl, texture, with_texture, allow_outside):
    """Random MTL files and texture bytes behind a valid OBJ."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "mesh"
        root.mkdir()
        (Path(tmp) / "t.png").write_bytes(texture)
        files = {"m.obj": "mtllib m.mtl\nusemtl a\n" + _VALID, "sub": None,
                 "m.mtl": "newmtl a\n" + "\n".join(mtl) + "\n"}
        if with_texture:
            files["t.png"] = texture
        _write_tree(root, files)
        d = outcome(load_obj, root / "m.obj", allow_outside=allow_outside)
        if d is not None:
            check_obj(d)
        m = outcome(load_mesh, root / "m.obj", allow_outside=allow_outside)
        if m is not None:
            check_mesh(m)


@FUZZ
@given(cut=st.integers(0, 400), pos=st.integers(0, 400), new=st.binary(max_size=6))
def test_fuzz_obj_bytes(cut, pos, new):
    """Byte mutations and truncations of a small valid OBJ with normals and UVs."""
    base = (_VALID + "vn 0 0 1\nf 1/1/1 2/2/1 4/3/1\nf -1 -2 -3\nf 1 2 3 4\n").encode()
    data = _mutate(base, pos, new)[: max(cut, 1)] if cut % 3 else _mutate(base, pos, new)
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "m.obj"
        p.write_bytes(data)
        d = outcome(load_obj, p)
        if d is not None:
            check_obj(d)


# --------------------------------------------------------------------------- point clouds
def _ply(fmt: str, n: int, body_n: int, props=("float x", "float y", "float z")) -> bytes:
    head = (f"ply\nformat {fmt} 1.0\nelement vertex {n}\n"
            + "".join(f"property {p}\n" for p in props) + "end_header\n").encode()
    rng = np.random.default_rng(body_n)
    vals = rng.normal(size=(body_n, len(props)))
    if fmt == "ascii":
        return head + "".join(" ".join(map(repr, r)) + "\n" for r in vals.tolist()).encode()
    e = "<" if "little" in fmt else ">"
    return head + vals.astype(e + "f4").tobytes()


@FUZZ
@given(fmt=st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian", "binary"]),
       n=st.one_of(st.integers(0, 6), st.sampled_from([10**8, 2**63, -1])),
       body_n=st.integers(0, 6), pos=st.integers(0, 300), new=st.binary(max_size=4),
       props=st.sampled_from([("float x", "float y", "float z"),
                              ("double x", "double y", "double z", "uchar red", "uchar green",
                               "uchar blue"),
                              ("float x", "float y"), ("list uchar int x", "float y", "float z"),
                              ("float x", "float y", "float z", "float nx", "float ny",
                               "float nz")]))
def test_fuzz_ply(fmt, n, body_n, pos, new, props):
    """PLY headers whose counts disagree with their bodies, odd properties, mutated bytes."""
    data = _mutate(_ply(fmt, n, body_n, props), pos, new) if new else _ply(fmt, n, body_n, props)
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "c.ply"
        p.write_bytes(data)
        c = outcome(load_pointcloud, p)
        if c is not None:
            assert len(c.points) == n and np.isfinite(c.points).all()
            assert c.features is None or np.isfinite(c.features).all()


def _npz(arrays: dict, compressed: bool) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


@FUZZ
@given(key=st.sampled_from(["verts", "points", "xyz"]),
       shape=st.sampled_from([(5, 3), (0, 3), (5, 2), (5,), (5, 3, 1)]),
       dtype=st.sampled_from(["f8", "f4", "i4", "u1", "c16", "U3", "b1"]),
       colours=st.sampled_from([None, "rgb_u8", "rgb_f", "rgb_big", "rgb_short"]),
       compressed=st.booleans(), pos=st.integers(0, 2000), new=st.binary(max_size=4),
       cut=st.integers(0, 3000))
def test_fuzz_npz(key, shape, dtype, colours, compressed, pos, new, cut):
    """npz archives with odd keys, shapes and dtypes, then byte mutations and truncations."""
    arrays = {key: np.ones(shape).astype(dtype)}
    n = shape[0]
    if colours == "rgb_u8":
        arrays["rgb"] = np.full((n, 3), 200, np.uint8)
    elif colours == "rgb_f":
        arrays["rgb"] = np.full((n, 3), 0.5)
    elif colours == "rgb_big":
        arrays["rgb"] = np.full((n, 3), 1000, np.int32)
    elif colours == "rgb_short":
        arrays["rgb"] = np.zeros((max(n - 1, 0), 3))
    data = _npz(arrays, compressed)
    if new:
        data = _mutate(data, pos, new)
    if cut < len(data) and cut % 2:
        data = data[:cut]
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "c.npz"
        p.write_bytes(data)
        c = outcome(load_pointcloud, p)
        if c is not None:
            assert np.isfinite(c.points).all() and c.points.shape[1] == 3
            assert c.features is None or np.isfinite(c.features).all()


@pytest.mark.parametrize("name", ["missing.ply", "missing.npz", "dir.ply", "x.xyz"])
def test_fuzz_paths_that_are_not_files(tmp_path, name):
    """Missing files and directories: FileNotFoundError or ValueError, never OSError."""
    (tmp_path / "dir.ply").mkdir()
    assert outcome(load_pointcloud, tmp_path / name) is None
    (tmp_path / "d.obj").mkdir()
    assert outcome(load_obj, tmp_path / "d.obj") is None
    assert outcome(load_mesh, tmp_path / "d.obj") is None
