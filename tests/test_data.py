"""geofit.data: data folders, checked downloads (offline: file:// and loopback http), fallbacks."""
from __future__ import annotations

import functools
import hashlib
import http.server
import socket
import threading
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial import ConvexHull

import geofit.data as gd
from geofit import Mesh, TexturesUV, ico_sphere
from geofit.io import save_obj


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.fixture
def dirs(tmp_path, monkeypatch):
    """Isolate the data folders: GEOFIT_DATA unset, cache under tmp_path, no shipped cow."""
    monkeypatch.delenv("GEOFIT_DATA", raising=False)
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    return tmp_path


@pytest.fixture
def mirror(tmp_path):
    """A local mirror folder with two files, and their checksums."""
    root = tmp_path / "mirror"
    (root / "a").mkdir(parents=True)
    files = {"a/one.txt": b"first file\n", "two.bin": bytes(range(256)) * 300}
    for name, data in files.items():
        (root / name).write_bytes(data)
    return root, {n: sha(d) for n, d in files.items()}, files


def leftovers(folder: Path) -> list:
    return [p.name for p in folder.rglob("*.part")]


# --------------------------------------------------------------------------- locations
def test_data_dir_resolution(tmp_path, monkeypatch):
    """GEOFIT_DATA first, then $XDG_CACHE_HOME/geofit, then ~/.cache/geofit."""
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert gd.data_dir() == tmp_path / "mine"
    assert gd.cache_dir() == tmp_path / "xdg" / "geofit"
    monkeypatch.delenv("GEOFIT_DATA")
    assert gd.data_dir() == tmp_path / "xdg" / "geofit"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert gd.data_dir() == tmp_path / "home" / ".cache" / "geofit"


def test_find_searches_geofit_data_then_cache(dirs, monkeypatch):
    mine, cache = dirs / "mine", gd.cache_dir()
    (mine / "dolphin").mkdir(parents=True)
    (cache / "cow_mesh").mkdir(parents=True)
    (cache / "dolphin").mkdir(parents=True)
    (mine / "dolphin" / "dolphin.obj").write_text("x")
    (cache / "dolphin" / "dolphin.obj").write_text("y")
    (cache / "cow_mesh" / "cow.obj").write_text("z")
    assert gd.find("dolphin/dolphin.obj") == cache / "dolphin" / "dolphin.obj"
    monkeypatch.setenv("GEOFIT_DATA", str(mine))
    assert gd.find("dolphin/dolphin.obj") == mine / "dolphin" / "dolphin.obj"
    assert gd.find("cow_mesh/cow.obj") == cache / "cow_mesh" / "cow.obj"  # falls back
    assert gd.find("cow_mesh/cow.mtl") is None
    # verify=True rejects files whose sha256 is not the registry's
    assert gd.find("dolphin/dolphin.obj", verify=True) is None
    for bad in ("/etc/passwd", "../x.obj", ""):
        with pytest.raises(ValueError, match="name: expected a relative"):
            gd.find(bad)


# --------------------------------------------------------------------------- download
def test_download_file_url_writes_verified_files(dirs, mirror):
    root, sums, content = mirror
    dest = dirs / "dest"
    out = gd.download(dest, base_url=root.as_uri(), files=sums)
    assert set(out) == set(sums)
    for name, data in content.items():
        assert out[name] == dest / name and out[name].read_bytes() == data
    assert leftovers(dest) == []
    # Present and valid: not fetched again (the mirror may even be gone) ...
    (root / "two.bin").unlink()
    assert gd.download(dest, base_url=root.as_uri(), files=sums) == out
    # ... unless forced.
    with pytest.raises(gd.DataUnavailableError, match=r"two\.bin"):
        gd.download(dest, base_url=root.as_uri(), files=sums, force=True)
    assert (dest / "two.bin").read_bytes() == content["two.bin"]  # the old copy is intact
    assert leftovers(dest) == []


def test_download_default_dest_is_the_cache_and_find_sees_it(dirs, mirror):
    root, sums, _ = mirror
    out = gd.download(base_url=root.as_uri() + "/", files={"a/one.txt": sums["a/one.txt"]})
    assert out["a/one.txt"] == gd.cache_dir() / "a" / "one.txt"
    assert gd.find("a/one.txt") == out["a/one.txt"]


def test_download_checksum_mismatch_leaves_no_file(dirs, mirror):
    root, sums, _ = mirror
    dest = dirs / "dest"
    wrong = {"a/one.txt": "0" * 64}
    with pytest.raises(ValueError, match=r"one\.txt: sha256 mismatch, expected 0{64}, got "
                                         + sums["a/one.txt"]):
        gd.download(dest, base_url=root.as_uri(), files=wrong)
    assert not (dest / "a" / "one.txt").exists() and leftovers(dest) == []


def test_download_replaces_a_corrupt_existing_file(dirs, mirror):
    root, sums, content = mirror
    dest = dirs / "dest"
    (dest / "a").mkdir(parents=True)
    (dest / "a" / "one.txt").write_bytes(b"corrupt")
    gd.download(dest, base_url=root.as_uri(), files={"a/one.txt": sums["a/one.txt"]})
    assert (dest / "a" / "one.txt").read_bytes() == content["a/one.txt"]


def test_download_registry_names_are_checked_against_registry_sums(dirs, tmp_path):
    """Group names expand to registry files; a fake 'cow' fails the registry checksum."""
    fake = tmp_path / "fake"
    (fake / "cow_mesh").mkdir(parents=True)
    for n in gd.GROUPS["cow"]:
        (fake / n).write_bytes(b"not the cow")
    with pytest.raises(ValueError, match=r"cow_mesh/cow\.obj: sha256 mismatch, expected "
                                         + gd.FILES["cow_mesh/cow.obj"][1]):
        gd.download(tmp_path / "dest", base_url=fake.as_uri(), files="cow")
    assert not (tmp_path / "dest" / "cow_mesh" / "cow.obj").exists()
    assert leftovers(tmp_path / "dest") == []


def test_download_default_files_are_the_whole_registry(dirs, tmp_path):
    """files=None asks for every registry file: the first missing one is reported."""
    with pytest.raises(gd.DataUnavailableError, match=r"dolphin/dolphin\.obj") as info:
        gd.download(tmp_path / "dest", base_url=(tmp_path / "void").as_uri())
    for name in gd.FILES:
        assert name in str(info.value)


def test_download_missing_local_file_is_unavailable(dirs, mirror):
    root, _, _ = mirror
    with pytest.raises(gd.DataUnavailableError) as info:
        gd.download(dirs / "dest", base_url=root.as_uri(), files="dolphin")
    msg = str(info.value)
    assert isinstance(info.value, RuntimeError)
    assert "dolphin/dolphin.obj" in msg and "GEOFIT_DATA" in msg
    assert gd.FILES["dolphin/dolphin.obj"][1] in msg and str(dirs / "dest") in msg


def test_download_argument_errors(dirs):
    with pytest.raises(ValueError, match="files: unknown tutorial file 'horse'"):
        gd.download(dirs, files=["horse"])
    with pytest.raises(ValueError, match=r"files\['x'\]: expected a 64-digit hex sha256"):
        gd.download(dirs, files={"x": "abc"})
    with pytest.raises(ValueError, match="name: expected a relative path"):
        gd.download(dirs, files={"../x": "0" * 64})
    with pytest.raises(ValueError, match="base_url: expected a URL string"):
        gd.download(dirs, base_url="", files="dolphin")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_download_unreachable_host_raises_data_unavailable(dirs):
    url = f"http://127.0.0.1:{free_port()}/data"  # nothing listens there
    with pytest.raises(gd.DataUnavailableError, match=r"could not download http://127\.0\.0\.1.*"
                                                      r"dolphin\.obj"):
        gd.download(dirs / "dest", base_url=url, files="dolphin", timeout=5)
    assert not (dirs / "dest" / "dolphin" / "dolphin.obj").exists()


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # keep the test output clean
        pass


def test_download_over_loopback_http(dirs, mirror):
    """A real HTTP server on 127.0.0.1 in a thread: files arrive verified; 404 is reported."""
    root, sums, content = mirror
    handler = functools.partial(QuietHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05},
                              daemon=True)
    thread.start()
    try:
        base = f"http://127.0.0.1:{server.server_address[1]}"
        out = gd.download(dirs / "dest", base_url=base, files=sums, timeout=10)
        for name, data in content.items():
            assert out[name].read_bytes() == data
        with pytest.raises(gd.DataUnavailableError, match=r"HTTP 404"):
            gd.download(dirs / "dest", base_url=base, files={"nope.txt": "0" * 64}, timeout=10)
        assert not (dirs / "dest" / "nope.txt").exists()
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)
    assert not thread.is_alive()
    assert leftovers(dirs / "dest") == []


# --------------------------------------------------------------------------- procedural meshes
def signed_volume(m: Mesh) -> float:
    v = m.verts[m.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6)


def depth_inside_hull(verts: np.ndarray) -> np.ndarray:
    """Distance of each vertex inside the convex hull (0 on the hull)."""
    h = ConvexHull(verts)
    return -(verts @ h.equations[:, :3].T + h.equations[:, 3]).max(axis=1)


def test_procedural_target_is_a_closed_nonconvex_genus0_shape():
    """Deterministic, watertight, Euler characteristic 2, outward, non-convex, tutorial frame."""
    m = gd.procedural_target()
    assert (m.n_verts, m.n_faces) == (2562, 5120)
    np.testing.assert_array_equal(m.faces, ico_sphere(4).faces)
    np.testing.assert_array_equal(m.verts, gd.procedural_target().verts)
    assert m.topology.is_watertight
    assert m.topology.euler_characteristic == 2
    assert signed_volume(m) > 0  # counter-clockwise seen from outside
    assert m.face_areas.min() > 1e-5  # no degenerate triangles
    np.testing.assert_allclose(m.verts.mean(0), 0, atol=1e-12)
    assert np.abs(m.verts).max() == pytest.approx(1.0, abs=1e-12)
    depth = depth_inside_hull(m.verts)
    assert depth.max() > 0.05  # some vertices lie well inside the hull: non-convex
    assert np.count_nonzero(depth > 0.02) > 100  # ... over whole regions, not one vertex


def test_procedural_textured_mesh_uv_layout_and_texture():
    """Closed ellipsoid, seam-aware UVs (no face wraps), texture in [0, 1] with detail."""
    m = gd.procedural_textured_mesh()
    m2 = gd.procedural_textured_mesh()
    np.testing.assert_array_equal(m.verts, m2.verts)
    np.testing.assert_array_equal(m.textures.maps, m2.textures.maps)
    assert (m.n_verts, m.n_faces) == (31 * 64 + 2, 2 * 31 * 64)
    assert m.topology.is_watertight and m.topology.euler_characteristic == 2
    assert signed_volume(m) > 0
    t = m.textures
    assert isinstance(t, TexturesUV)
    assert t.maps.shape == (512, 512, 3) and t.maps.dtype == np.float64
    assert t.maps.min() >= 0 and t.maps.max() <= 1
    assert t.maps.std() > 0.1  # a real pattern, not a flat colour
    assert len(t.verts_uvs) > m.n_verts  # the seam and the poles are split in UV space
    assert t.verts_uvs.min() >= 0 and t.verts_uvs.max() <= 1
    fu = t.face_uvs()
    assert np.ptp(fu[:, :, 0], axis=1).max() < 0.1  # no triangle wraps around the seam
    e1, e2 = fu[:, 1] - fu[:, 0], fu[:, 2] - fu[:, 0]
    uv_area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    assert uv_area.min() > 0  # UV triangles are not flipped
    # The texture varies across the surface: face-centre colours cover many values.
    col = m.sample_textures(np.arange(m.n_faces), np.full((m.n_faces, 3), 1 / 3))
    assert len(np.unique(np.round(col, 3), axis=0)) > 500
    assert np.all(depth_inside_hull(m.verts) < 1e-9)  # it is convex (an ellipsoid)
    small = gd.procedural_textured_mesh(n_lat=4, n_lon=5, texture_size=16)
    assert (small.n_verts, small.n_faces) == (17, 30) and small.topology.euler_characteristic == 2


@pytest.mark.parametrize("kw", [{"n_lat": 2}, {"n_lon": 2.5}, {"texture_size": 8},
                                {"n_lat": True}])
def test_procedural_textured_mesh_validation(kw):
    with pytest.raises(ValueError, match=f"{next(iter(kw))}: expected an integer >="):
        gd.procedural_textured_mesh(**kw)


# --------------------------------------------------------------------------- loaders
def test_loaders_fall_back_to_procedural_meshes(dirs, monkeypatch):
    monkeypatch.setenv("GEOFIT_DATA", str(dirs / "empty"))
    tgt = gd.load_target_mesh()
    assert tgt.name == "procedural_target" and tgt.path is None
    np.testing.assert_array_equal(tgt.mesh.verts, gd.procedural_target().verts)
    tex = gd.load_textured_mesh()
    assert tex.name == "procedural_textured" and tex.path is None
    assert isinstance(tex.mesh.textures, TexturesUV)


def test_loaders_use_files_under_geofit_data(dirs, monkeypatch):
    """Files placed under $GEOFIT_DATA are what the loaders return (with their names)."""
    root = dirs / "mine"
    (root / "dolphin").mkdir(parents=True)
    (root / "cow_mesh").mkdir(parents=True)
    sphere = ico_sphere(1)
    save_obj(root / "dolphin" / "dolphin.obj", sphere)
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    fuv = np.tile([0, 1, 2], (sphere.n_faces, 1))
    maps = np.arange(2 * 2 * 3).reshape(2, 2, 3) / 255.0
    save_obj(root / "cow_mesh" / "cow.obj", sphere.verts, sphere.faces, verts_uvs=uv,
             faces_uvs=fuv, texture_map=maps)
    monkeypatch.setenv("GEOFIT_DATA", str(root))
    tgt = gd.load_target_mesh()
    assert tgt.name == "dolphin" and tgt.path == root / "dolphin" / "dolphin.obj"
    np.testing.assert_array_equal(tgt.mesh.verts, sphere.verts)
    tex = gd.load_textured_mesh()
    assert tex.name == "cow" and tex.path == root / "cow_mesh" / "cow.obj"
    np.testing.assert_array_equal(tex.mesh.textures.maps, maps)
    np.testing.assert_array_equal(tex.mesh.textures.faces_uvs, fuv)
    assert np.asarray(Image.open(root / "cow_mesh" / "cow.png")).shape == (2, 2, 3)


# --------------------------------------------------------------------------- the shipped cow
def test_shipped_cow_is_the_default_offline(dirs, monkeypatch):
    """With no GEOFIT_DATA and an empty cache, the cow installed with geofit is loaded."""
    monkeypatch.delenv("GEOFIT_SHIPPED_DATA")
    shipped = gd.shipped_dir()
    assert shipped is not None
    for name in gd.GROUPS["cow"]:  # byte for byte the checked tutorial files
        assert gd.find(name, verify=True) == shipped / name
    tex = gd.load_textured_mesh()
    assert tex.name == "cow" and tex.path == shipped / "cow_mesh" / "cow.obj"
    assert (tex.mesh.n_verts, tex.mesh.n_faces) == (2930, 5856)
    assert tex.mesh.textures.maps.shape == (1024, 1024, 3)
    assert gd.load_target_mesh().name == "procedural_target"  # the dolphin is not shipped
    assert "CC0" in (shipped / "README.md").read_text()


def test_geofit_data_and_cache_come_before_the_shipped_cow(dirs, monkeypatch):
    """Lookup order: GEOFIT_DATA, then the user cache, then the shipped data."""
    monkeypatch.delenv("GEOFIT_SHIPPED_DATA")
    mine, cache = dirs / "mine", gd.cache_dir()
    for root in (mine, cache):
        (root / "cow_mesh").mkdir(parents=True)
        (root / "cow_mesh" / "cow.mtl").write_text(f"# {root.name}\n")
    monkeypatch.setenv("GEOFIT_DATA", str(mine))
    assert gd.find("cow_mesh/cow.mtl") == mine / "cow_mesh" / "cow.mtl"
    (mine / "cow_mesh" / "cow.mtl").unlink()
    assert gd.find("cow_mesh/cow.mtl") == cache / "cow_mesh" / "cow.mtl"
    (cache / "cow_mesh" / "cow.mtl").unlink()
    assert gd.find("cow_mesh/cow.mtl") == gd.shipped_dir() / "cow_mesh" / "cow.mtl"
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")
    assert gd.shipped_dir() is None and gd.find("cow_mesh/cow.mtl") is None


def test_setup_cfg_installs_the_shipped_files():
    """package_data names every shipped file (so a regular install carries the cow)."""
    import configparser
    import fnmatch

    root = Path(gd.__file__).resolve().parents[1]
    if not (root / "setup.cfg").is_file():
        pytest.skip("geofit is installed, not run from its source tree")
    cfg = configparser.ConfigParser()
    cfg.read(root / "setup.cfg")
    patterns = cfg["options.package_data"]["geofit"].split()
    shipped = [p.relative_to(root / "data").as_posix() for p in (root / "data").rglob("*")
               if p.is_file()]
    assert shipped and all(any(fnmatch.fnmatch(f"_data/{f}", pat) for pat in patterns)
                           for f in shipped)
    assert (root / "geofit" / "_data" / "cow_mesh" / "cow.obj").is_file()
