"""geofit.io: OBJ/MTL/PNG reading and writing, point cloud files."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _helpers import glb_round_trip
from PIL import Image

import geofit.data
from geofit import Mesh, PointCloud, TexturesUV, TexturesVertex, ico_sphere
from geofit.io import (Material, ObjData, load_mesh, load_obj, load_objs_as_meshes,
                       load_pointcloud, save_mesh, save_obj, save_pointcloud)

DATA = Path(__file__).parent / "data"


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def png(path: Path, rgb: np.ndarray) -> Path:
    Image.fromarray(np.asarray(rgb, dtype=np.uint8)).save(path)
    return path


QUAD_PENTA = """\
# a quad and a pentagon
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 2 0 0
v 3 0 0
v 3 1 0
v 2.5 2 0
v 2 1 0
f 1 2 3 4
f 5 6 7 8 9
"""


# --------------------------------------------------------------------------- parsing
def test_fan_triangulation_quad_and_pentagon(tmp_path):
    """A k-gon becomes k-2 triangles (v0, vi, vi+1), in file order."""
    d = load_obj(write(tmp_path / "m.obj", QUAD_PENTA))
    assert isinstance(d, ObjData)
    np.testing.assert_array_equal(
        d.faces, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [4, 7, 8]])
    assert d.faces.dtype == np.int64 and d.verts.dtype == np.float64
    assert d.verts.shape == (9, 3)
    np.testing.assert_array_equal(d.faces_uvs, -np.ones((5, 3)))
    np.testing.assert_array_equal(d.faces_normals_idx, -np.ones((5, 3)))
    assert d.verts_uvs.shape == (0, 2) and d.normals.shape == (0, 3)
    np.testing.assert_array_equal(d.face_materials, -np.ones(5))
    assert d.materials == {} and d.texture_images == {} and d.material_names == []


def test_fan_triangulation_carries_uv_and_normal_indices(tmp_path):
    """Per-corner vt and vn indices are triangulated with the same fan as the vertices."""
    text = ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
            "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
            "vn 0 0 1\nvn 0 0 -1\n"
            "f 1/5/1 2/4/2 3/3/1 4/2/2\n")
    d = load_obj(write(tmp_path / "m.obj", text))
    np.testing.assert_array_equal(d.faces, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(d.faces_uvs, [[4, 3, 2], [4, 2, 1]])
    np.testing.assert_array_equal(d.faces_normals_idx, [[0, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(d.verts_uvs[4], [0.5, 0.5])


def test_corner_forms_and_missing_attributes(tmp_path):
    """v, v/vt, v//vn and v/vt/vn forms; faces without vt/vn get -1 there."""
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
            "vt 0.25 0.75\nvt 1 0\nvt 0 1\n"
            "vn 1 0 0\nvn 0 1 0\nvn 0 0 1\n"
            "f 1 2 3\n"
            "f 1/1 2/2 4/3\n"
            "f 1//3 3//2 4//1\n"
            "f 2/3/1 3/2/2 4/1/3\n")
    d = load_obj(write(tmp_path / "m.obj", text))
    np.testing.assert_array_equal(d.faces, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    np.testing.assert_array_equal(d.faces_uvs, [[-1] * 3, [0, 1, 2], [-1] * 3, [2, 1, 0]])
    np.testing.assert_array_equal(d.faces_normals_idx,
                                  [[-1] * 3, [-1] * 3, [2, 1, 0], [0, 1, 2]])
    np.testing.assert_array_equal(d.verts_uvs[0], [0.25, 0.75])
    np.testing.assert_array_equal(d.normals, np.eye(3))


def test_relative_indices_match_absolute(tmp_path):
    """-1 is the last vertex defined before the face line (all vertices first: = PyTorch3D)."""
    rel = QUAD_PENTA.replace("f 1 2 3 4", "f -9 -8 -7 -6").replace("f 5 6 7 8 9",
                                                                   "f -5 -4 -3 -2 -1")
    a = load_obj(write(tmp_path / "abs.obj", QUAD_PENTA))
    b = load_obj(write(tmp_path / "rel.obj", rel))
    np.testing.assert_array_equal(a.faces, b.faces)


def test_relative_indices_count_from_the_face_line(tmp_path):
    """Interleaved v/f: relative indices refer to the vertices defined so far (OBJ spec)."""
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3/-2 -2/-1 -1/-1\n"
            "vt 0 0\nvt 1 1\n"  # defined after the face: the face's vt refer to earlier ones
            "v 5 0 0\nv 6 0 0\nv 5 1 0\nf -3 -2 -1\n")
    text = "vt 0.5 0.5\nvt 0.1 0.2\n" + text
    d = load_obj(write(tmp_path / "m.obj", text))
    np.testing.assert_array_equal(d.faces, [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(d.faces_uvs, [[0, 1, 1], [-1, -1, -1]])


def test_latin1_file(tmp_path):
    """A file that is not valid UTF-8 (a Latin-1 comment) still loads."""
    p = tmp_path / "l.obj"
    p.write_bytes(b"# caf\xe9 model\n" + QUAD_PENTA.encode())
    assert load_obj(p).faces.shape == (5, 3)


def test_comments_extra_values_and_materials(tmp_path):
    """Comments are ignored, extra v/vt values dropped, usemtl order indexes face_materials."""
    text = ("# header\n"
            "v 0 0 0 1.0 0.5 0.25  # x y z r g b\n"
            "v 1 0 0 1 1 1\nv 0 1 0 0 0 0\nv 1 1 0 0 0 0\n"
            "vt 0.5 0.5 0.0\n"
            "f 1 2 3\n"
            "usemtl B\nf 2 4 3\n"
            "usemtl A\nf 1 3 4\n"
            "usemtl B\nf 1 2 4  # again\n")
    d = load_obj(write(tmp_path / "m.obj", text))
    np.testing.assert_array_equal(d.verts[0], [0, 0, 0])
    np.testing.assert_array_equal(d.verts_uvs, [[0.5, 0.5]])
    assert d.material_names == ["B", "A"]
    np.testing.assert_array_equal(d.face_materials, [-1, 0, 1, 0])
    assert d.materials == {}  # no mtllib


def test_materials_and_textures_from_mtl(tmp_path):
    """MTL keys Ka/Kd/Ks/Ns/map_Kd; texture images RGB/255 with row 0 at the top; used order."""
    (tmp_path / "sub").mkdir()
    top = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]])
    bottom = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90]])
    png(tmp_path / "sub" / "tex_a.png", np.stack([top, bottom]))
    png(tmp_path / "sub" / "tex_b.png", np.full((4, 5, 3), 128))
    write(tmp_path / "sub" / "m.mtl",
          "newmtl unused\nKd 0 0 0\nillum 2\nmap_Bump nothing.png\n"
          "newmtl matB\nKa 0.1 0.2 0.3\nKd 0.5  # grey\nKs 0 0 0\nNs 12.5\nmap_Kd tex_b.png\n"
          "newmtl matA\nmap_Kd -s 1 1 1 tex_a.png\n")
    text = ("mtllib sub/m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
            "usemtl matA\nf 1/1 2/2 3/3\nusemtl matB\nf 1/1 3/3 2/2\nusemtl nowhere\nf 3 2 1\n")
    d = load_obj(write(tmp_path / "m.obj", text))
    assert d.material_names == ["matA", "matB", "nowhere"]
    assert list(d.materials) == ["matA", "matB"]  # used and defined, in order of use
    b = d.materials["matB"]
    assert isinstance(b, Material)
    np.testing.assert_array_equal(b.Ka, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(b.Kd, [0.5, 0.5, 0.5])
    np.testing.assert_array_equal(b.Ks, [0, 0, 0])
    assert b.Ns == 12.5
    assert Path(b.map_Kd) == tmp_path / "sub" / "tex_b.png"
    assert d.materials["matA"].Kd is None
    assert list(d.texture_images) == ["matA", "matB"]
    img = d.texture_images["matA"]
    assert img.shape == (2, 3, 3) and img.dtype == np.float64
    np.testing.assert_array_equal(img[0], top / 255.0)
    np.testing.assert_array_equal(img[1], bottom / 255.0)
    np.testing.assert_array_equal(d.face_materials, [0, 1, 2])
    # Without textures the MTL is not read at all.
    d2 = load_obj(tmp_path / "m.obj", load_textures=False)
    assert d2.materials == {} and d2.texture_images == {}
    np.testing.assert_array_equal(d2.faces, d.faces)
    # load_objs_as_meshes uses only the first texture image (in order of use).
    m = load_objs_as_meshes([tmp_path / "m.obj"])[0]
    np.testing.assert_array_equal(m.textures.maps, img)


def test_load_objs_as_meshes_textures_like_pytorch3d(tmp_path):
    """Textured OBJ -> TexturesUV(first map, faces_uvs, verts_uvs); untextured -> None."""
    png(tmp_path / "t.png", np.arange(2 * 2 * 3).reshape(2, 2, 3) * 20)
    write(tmp_path / "t.mtl", "newmtl m\nKd 1 0 0\nmap_Kd t.png\n")
    write(tmp_path / "t.obj", "mtllib t.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
          "vt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\nf 2 4 3\n")
    write(tmp_path / "plain.obj", QUAD_PENTA)
    ms = load_objs_as_meshes([tmp_path / "t.obj", str(tmp_path / "plain.obj")])
    assert len(ms) == 2
    t = ms[0].textures
    assert isinstance(t, TexturesUV)
    np.testing.assert_array_equal(t.verts_uvs, [[0, 0], [1, 0], [0, 1]])
    # The face without vt uses the last UV, as PyTorch3D's -1 indexing does.
    np.testing.assert_array_equal(t.faces_uvs, [[0, 1, 2], [2, 2, 2]])
    np.testing.assert_array_equal(t.maps * 255, np.arange(12).reshape(2, 2, 3) * 20)
    assert ms[1].textures is None and ms[1].n_faces == 5
    assert load_objs_as_meshes(tmp_path / "t.obj", load_textures=False)[0].textures is None
    single = load_mesh(tmp_path / "t.obj")
    np.testing.assert_array_equal(single.faces, ms[0].faces)
    assert isinstance(single.textures, TexturesUV)


def test_texture_without_uvs_raises(tmp_path):
    png(tmp_path / "t.png", np.zeros((2, 2, 3)))
    write(tmp_path / "t.mtl", "newmtl m\nmap_Kd t.png\n")
    write(tmp_path / "t.obj", "mtllib t.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"t\.obj.*no texture coordinates"):
        load_objs_as_meshes([tmp_path / "t.obj"])
    assert load_obj(tmp_path / "t.obj").texture_images["m"].shape == (2, 2, 3)


def reference_parse(text: str):
    """Slow line-by-line OBJ parser (spec semantics) to check the vectorised one against."""
    v, vt, vn, faces, fuv, fnv, fmat, names = [], [], [], [], [], [], [], []
    cur = -1
    for line in text.splitlines():
        tok = line.split("#")[0].split()
        if not tok:
            continue
        if tok[0] == "v":
            v.append([float(x) for x in tok[1:4]])
        elif tok[0] == "vt":
            vt.append([float(x) for x in tok[1:3]])
        elif tok[0] == "vn":
            vn.append([float(x) for x in tok[1:4]])
        elif tok[0] == "usemtl":
            if tok[1] not in names:
                names.append(tok[1])
            cur = names.index(tok[1])
        elif tok[0] == "f":
            corners = []
            for c in tok[1:]:
                parts = c.split("/") + ["", ""]
                out = []
                for s_, n in zip(parts[:3], (len(v), len(vt), len(vn))):
                    out.append(-1 if s_ == "" else (int(s_) - 1 if int(s_) > 0 else n + int(s_)))
                corners.append(out)
            for i in range(1, len(corners) - 1):
                tri = [corners[0], corners[i], corners[i + 1]]
                faces.append([c[0] for c in tri])
                fuv.append([c[1] for c in tri])
                fnv.append([c[2] for c in tri])
                fmat.append(cur)
    return np.array(v), np.array(vt), np.array(vn), np.array(faces), np.array(fuv), \
        np.array(fnv), np.array(fmat), names


def random_obj(rng) -> str:
    """Interleaved v/vt/vn/f/usemtl lines, polygons of 3-6 corners, every corner form, absolute
    and relative indices, tabs, repeated spaces, comments and explicit '+' signs."""
    out, nv, nt, nn = [], 0, 0, 0
    for _ in range(300):
        kind = rng.choice(["v", "vt", "vn", "f", "f", "f", "usemtl"], p=[.3, .1, .1, .15, .15,
                                                                          .15, .05])
        if kind == "v" or nv < 3:
            out.append("v " + " ".join(repr(float(x)) for x in rng.normal(size=3)))
            nv += 1
        elif kind == "vt":
            u, w = rng.uniform(size=2).tolist()
            out.append(f"vt\t{u!r} {w!r}")
            nt += 1
        elif kind == "vn":
            a, b, c = rng.normal(size=3).tolist()
            out.append(f"vn {a!r}  {b!r} {c!r}  # unit-ish")
            nn += 1
        elif kind == "usemtl":
            out.append(f"usemtl m{rng.integers(3)}")
        else:
            k = int(rng.integers(3, 7))
            use_t = nt > 0 and rng.random() < 0.5
            use_n = nn > 0 and rng.random() < 0.5
            rel = rng.random() < 0.3

            def ref(n, rel=rel):
                i = int(rng.integers(1, n + 1))
                return str(i - n - 1) if rel else ("+" if rng.random() < 0.1 else "") + str(i)
            corners = []
            for _ in range(k):
                c = ref(nv)
                if use_t and use_n:
                    c += f"/{ref(nt)}/{ref(nn)}"
                elif use_t:
                    c += f"/{ref(nt)}"
                elif use_n:
                    c += f"//{ref(nn)}"
                corners.append(c)
            out.append("f " + "  ".join(corners) + ("\t# face" if rng.random() < 0.2 else ""))
    out.append("f 1 2 3")
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("seed", range(5))
def test_vectorised_parser_matches_reference_loop(tmp_path, seed):
    """The byte-level tokeniser gives what a plain line-by-line parser gives."""
    text = random_obj(np.random.default_rng(seed))
    d = load_obj(write(tmp_path / "r.obj", text))
    v, vt, vn, faces, fuv, fnv, fmat, names = reference_parse(text)
    np.testing.assert_array_equal(d.verts, v)
    np.testing.assert_array_equal(d.verts_uvs, vt.reshape(-1, 2))
    np.testing.assert_array_equal(d.normals, vn.reshape(-1, 3))
    np.testing.assert_array_equal(d.faces, faces)
    np.testing.assert_array_equal(d.faces_uvs, fuv)
    np.testing.assert_array_equal(d.faces_normals_idx, fnv)
    np.testing.assert_array_equal(d.face_materials, fmat)
    assert d.material_names == names
    assert (fuv >= 0).any() and (fnv >= 0).any() and (fuv < 0).any()  # all forms occurred


# --------------------------------------------------------------------------- round trips
def test_round_trip_plain_mesh_is_exact(tmp_path):
    """save_obj then load_obj gives bit-identical float64 vertices and the same faces."""
    rng = np.random.default_rng(3)
    m = ico_sphere(2)
    v = m.verts * rng.uniform(0.1, 1e3) + rng.normal(size=m.verts.shape) * 1e-7
    v[0] = [1e-300, -3.5e17, np.pi]
    save_obj(tmp_path / "a.obj", v, m.faces)
    d = load_obj(tmp_path / "a.obj")
    np.testing.assert_array_equal(d.verts, v)
    np.testing.assert_array_equal(d.faces, m.faces)
    assert not (tmp_path / "a.mtl").exists() and not (tmp_path / "a.png").exists()
    save_obj(tmp_path / "b.obj", m.update_verts(v))
    np.testing.assert_array_equal(load_mesh(tmp_path / "b.obj").verts, v)


def test_round_trip_textured_mesh_is_exact(tmp_path):
    """A TexturesUV mesh round-trips: vt, per-corner UV indices, and an 8-bit texture."""
    rng = np.random.default_rng(4)
    verts = rng.normal(size=(5, 3))
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 4, 3]])
    verts_uvs = rng.uniform(size=(7, 2))
    faces_uvs = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [1, 6, 5]])
    maps = rng.integers(0, 256, size=(6, 9, 3)) / 255.0
    mesh = Mesh(verts, faces, TexturesUV(maps, faces_uvs, verts_uvs))
    save_obj(tmp_path / "tex.obj", mesh)
    assert (tmp_path / "tex.mtl").is_file() and (tmp_path / "tex.png").is_file()
    d = load_obj(tmp_path / "tex.obj")
    np.testing.assert_array_equal(d.verts, verts)
    np.testing.assert_array_equal(d.faces, faces)
    np.testing.assert_array_equal(d.verts_uvs, verts_uvs)
    np.testing.assert_array_equal(d.faces_uvs, faces_uvs)
    (img,) = d.texture_images.values()
    np.testing.assert_array_equal(img, maps)
    back = load_objs_as_meshes([tmp_path / "tex.obj"])[0]
    np.testing.assert_array_equal(back.textures.faces_uvs, faces_uvs)
    face, bary = np.array([0, 2, 3]), rng.dirichlet(np.ones(3), size=3)
    np.testing.assert_array_equal(back.sample_textures(face, bary),
                                  mesh.sample_textures(face, bary))


def test_round_trip_explicit_uv_arrays_and_grey_or_rgba_maps(tmp_path):
    """Arrays instead of a Mesh; 1- and 4-channel maps are written and read back as RGB."""
    verts, faces = np.eye(3), np.array([[0, 1, 2]])
    uv, fuv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[2, 1, 0]])
    save_obj(tmp_path / "uvonly.obj", verts, faces, verts_uvs=uv, faces_uvs=fuv)
    d = load_obj(tmp_path / "uvonly.obj")
    np.testing.assert_array_equal(d.faces_uvs, fuv)
    assert d.texture_images == {} and not (tmp_path / "uvonly.png").exists()
    grey = np.array([[0.0, 1.0], [51 / 255, 1.0]])
    save_obj(tmp_path / "g.obj", verts, faces, verts_uvs=uv, faces_uvs=fuv, texture_map=grey)
    (img,) = load_obj(tmp_path / "g.obj").texture_images.values()
    np.testing.assert_array_equal(img, np.repeat(grey[:, :, None], 3, axis=2))
    rgba = np.concatenate([np.full((2, 2, 3), 0.2), np.full((2, 2, 1), 0.6)], axis=2)
    save_obj(tmp_path / "c.obj", verts, faces, verts_uvs=uv, faces_uvs=fuv, texture_map=rgba)
    (img,) = load_obj(tmp_path / "c.obj").texture_images.values()
    np.testing.assert_array_equal(img, np.full((2, 2, 3), 51 / 255))


def test_decimal_places_rounds(tmp_path):
    v = np.array([[0.123456789, -1.987654321, 2.0], [1, 0, 0], [0, 1, 0]])
    save_obj(tmp_path / "r.obj", v, [[0, 1, 2]], decimal_places=3)
    d = load_obj(tmp_path / "r.obj")
    np.testing.assert_array_equal(d.verts[0], [0.123, -1.988, 2.0])
    assert "0.123 -1.988 2.000" in (tmp_path / "r.obj").read_text()


def test_vertex_textures_are_not_written(tmp_path):
    m = Mesh(np.eye(3), [[0, 1, 2]], TexturesVertex(np.ones((3, 3))))
    save_obj(tmp_path / "vc.obj", m)
    d = load_obj(tmp_path / "vc.obj")
    np.testing.assert_array_equal(d.verts, np.eye(3))
    assert d.texture_images == {}


def test_load_mesh_other_formats(tmp_path):
    """.ply through trimesh keeps the vertex order and faces."""
    m = ico_sphere(1)
    m.to_trimesh().export(tmp_path / "s.ply")
    back = load_mesh(tmp_path / "s.ply")
    np.testing.assert_allclose(back.verts, m.verts, rtol=0, atol=1e-6)  # PLY may hold float32
    np.testing.assert_array_equal(back.faces, m.faces)
    write(tmp_path / "flat.off", "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(ValueError, match=r"flat\.off.*no faces"):
        load_mesh(tmp_path / "flat.off")
    write(tmp_path / "nan.off", "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n")
    with pytest.raises(ValueError, match=r"nan\.off: the vertex coordinates are not all finite"):
        load_mesh(tmp_path / "nan.off")
    with pytest.raises(ValueError, match=r"path: expected one of \.obj, \.ply"):
        load_mesh(tmp_path / "s.3ds")
    with pytest.raises(FileNotFoundError, match=r"nope\.ply"):
        load_mesh(tmp_path / "nope.ply")


# --------------------------------------------------------------------------- load errors
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


@pytest.mark.parametrize(
    "text, match",
    [
        (TRI + "v 1 x 0\nf 1 2 3\n", r"line 4: vertex has a non-numeric value in '1 x 0'"),
        (TRI + "v 1 nan 0\nf 1 2 3\n", r"line 4: vertex is not finite"),
        (TRI + "vt 0 inf\nf 1 2 3\n", r"line 4: texture coordinate is not finite"),
        (TRI + "vn 0 1 -inf\nf 1 2 3\n", r"line 4: normal is not finite"),
        (TRI + "v 1 2\nf 1 2 3\n", r"line 4: vertex needs 3 coordinates"),
        (TRI + "vt 0\nf 1 2 3\n", r"line 4: texture coordinate needs 2 values"),
        (TRI + "vn 0 1\nf 1 2 3\n", r"line 4: normal needs 3 values"),
        (TRI + "f 1 2\n", r"line 4: face needs at least 3 vertices, got 2"),
        (TRI + "f 1 2 3\nf 1 2 4\n", (r"line 5: face vertex index 4 is out of range "
                                      r"\(the file has 3 vertex entries\)")),
        (TRI + "f 0 1 2\n", r"line 4: face vertex index 0 is invalid"),
        ("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n",
         r"line 3: face vertex relative index -3 points before the first vertex"),
        (TRI + "f 1 2 3.5\n", r"line 4: face has a non-integer vertex index '3.5'"),
        (TRI + "f 1 2 a\n", r"line 4: face has a non-integer vertex index 'a'"),
        (TRI + "vt 0 0\nf 1/1 2/2 3/1\n", (r"line 5: face texture coordinate index 2 is out of "
                                           r"range \(the file has 1 texture coordinate entries\)")),
        (TRI + "vn 0 0 1\nf 1//1 2//1 3//-2\n",
         r"line 5: face normal relative index -2 points before the first normal"),
        (TRI + "vt 0 0\nf 1/1 2 3/1\n", (r"line 5: face mixes corners with and without "
                                         r"texture coordinate indices")),
        (TRI + "vn 0 0 1\nf 1//1 2//1 3\n", (r"line 5: face mixes corners with and without "
                                             r"normal indices")),
        (TRI + "vt 0 0\nf 1/x 2/1 3/1\n", (r"line 5: face has a non-integer texture coordinate "
                                           r"index 'x'")),
        (TRI + "f 1/1/1/1 2 3\n", r"line 4: face corner '1/1/1/1' has more than 3"),
        (TRI + "f /1 2 3\n", r"line 4: face corner '/1' has no vertex index"),
        (TRI, r"has no faces \(empty mesh; 3 vertices\)"),
        ("", r"has no faces \(empty mesh; 0 vertices\)"),
        (TRI + "usemtl\nf 1 2 3\n", r"line 4: usemtl without a material name"),
        (TRI + "mtllib\nf 1 2 3\n", r"line 4: mtllib without a file name"),
    ],
)
def test_load_obj_errors(tmp_path, text, match):
    """Each malformed file raises ValueError naming the file and the line."""
    p = write(tmp_path / "bad.obj", text)
    with pytest.raises(ValueError, match=r"bad\.obj.*" + match):
        load_obj(p)


def test_load_obj_missing_files(tmp_path):
    """Missing OBJ or texture image: FileNotFoundError naming the file; missing MTL: a warning."""
    with pytest.raises(FileNotFoundError, match=r"OBJ file not found: .*none\.obj"):
        load_obj(tmp_path / "none.obj")
    p = write(tmp_path / "m.obj", "mtllib gone.mtl\nusemtl a\n" + TRI + "f 1 2 3\n")
    with pytest.warns(UserWarning, match=r"line 1: material library not found: .*gone\.mtl; "
                                         r"loading the geometry without its materials"):
        d = load_obj(p)  # PyTorch3D's behaviour: a warning, the geometry, no materials
    np.testing.assert_array_equal(d.faces, [[0, 1, 2]])
    assert d.materials == {} and d.texture_images == {} and d.material_names == ["a"]
    np.testing.assert_array_equal(load_obj(p, load_textures=False).faces, [[0, 1, 2]])
    write(tmp_path / "gone.mtl", "newmtl a\nmap_Kd missing_tex.png\n")
    with pytest.raises(FileNotFoundError, match=r"texture image of material 'a' not found: "
                                                r".*missing_tex\.png"):
        load_obj(p)
    with pytest.raises(FileNotFoundError, match="missing_tex"):
        load_objs_as_meshes([p])
    assert load_objs_as_meshes([p], load_textures=False)[0].n_faces == 1


@pytest.mark.parametrize(
    "mtl, match",
    [
        ("newmtl a\nKd 1 x 0\n", r"line 2: Kd has a non-numeric value"),
        ("Kd 1 1 1\n", r"line 1: Kd before any newmtl"),
        ("newmtl a\nKs 1 1\n", r"line 2: Ks needs 3 values"),
        ("newmtl a\nNs\n", r"line 2: Ns needs a value"),
        ("newmtl a\nmap_Kd\n", r"line 2: map_Kd without a file name"),
        ("newmtl\n", r"line 1: newmtl without a material name"),
    ],
)
def test_mtl_errors(tmp_path, mtl, match):
    write(tmp_path / "m.mtl", mtl)
    p = write(tmp_path / "m.obj", "mtllib m.mtl\n" + TRI + "f 1 2 3\n")
    with pytest.raises(ValueError, match=r"m\.mtl: " + match):
        load_obj(p)


# --------------------------------------------------------------------------- save errors
def test_save_obj_errors(tmp_path):
    m = ico_sphere(0)
    uv, fuv = np.zeros((3, 2)), np.zeros((20, 3), np.int64)
    p = tmp_path / "x.obj"
    with pytest.raises(ValueError, match="give them only with a vertex array"):
        save_obj(p, m, m.faces)
    with pytest.raises(ValueError, match="faces: required"):
        save_obj(p, m.verts)
    with pytest.raises(ValueError, match=r"verts: expected shape \(n, 3\), got \(12, 2\)"):
        save_obj(p, m.verts[:, :2], m.faces)
    with pytest.raises(ValueError, match="verts: expected finite values"):
        save_obj(p, np.where(np.arange(36).reshape(12, 3) == 5, np.nan, m.verts), m.faces)
    with pytest.raises(ValueError, match=r"faces: vertex indices must lie in \[0, 11\]"):
        save_obj(p, m.verts, m.faces + 1)
    with pytest.raises(ValueError, match="faces: expected a non-empty array"):
        save_obj(p, m.verts, np.zeros((0, 3), np.int64))
    with pytest.raises(ValueError, match="verts_uvs, faces_uvs: give both or neither"):
        save_obj(p, m.verts, m.faces, verts_uvs=uv)
    with pytest.raises(ValueError, match=r"faces_uvs: expected shape \(20, 3\), got \(19, 3\)"):
        save_obj(p, m.verts, m.faces, verts_uvs=uv, faces_uvs=fuv[:19])
    with pytest.raises(ValueError, match=r"faces_uvs: vertex indices must lie in \[0, 2\]"):
        save_obj(p, m.verts, m.faces, verts_uvs=uv, faces_uvs=fuv + 3)
    with pytest.raises(ValueError, match="texture_map: needs verts_uvs"):
        save_obj(p, m.verts, m.faces, texture_map=np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match=r"texture_map: expected shape \(H, W, C\) with C in"):
        save_obj(p, m.verts, m.faces, verts_uvs=uv, faces_uvs=fuv, texture_map=np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match=r"texture_map: expected values in \[0, 1\]"):
        save_obj(p, m.verts, m.faces, verts_uvs=uv, faces_uvs=fuv,
                 texture_map=np.full((2, 2, 3), 1.5))
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="decimal_places: expected None or an integer"):
            save_obj(p, m.verts, m.faces, decimal_places=bad)
    assert not p.exists()  # nothing was written by a failing call


# --------------------------------------------------------------------------- point clouds
def test_pointcloud_npz_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    pts, rgb, nrm = rng.normal(size=(50, 3)), rng.uniform(size=(50, 3)), rng.normal(size=(50, 3))
    save_pointcloud(tmp_path / "c.npz", PointCloud(pts, rgb, nrm))
    with np.load(tmp_path / "c.npz") as z:  # PittsburghBridge layout
        assert set(z.files) == {"verts", "rgb", "normals"}
    c = load_pointcloud(tmp_path / "c.npz")
    np.testing.assert_array_equal(c.points, pts)
    np.testing.assert_array_equal(c.features, rgb)
    np.testing.assert_array_equal(c.normals, nrm)
    save_pointcloud(tmp_path / "bare.npz", PointCloud(pts))
    c = load_pointcloud(tmp_path / "bare.npz")
    assert c.features is None and c.normals is None


def test_pointcloud_npz_colour_rule_and_alternative_keys(tmp_path):
    """uint8 colours are divided by 255; float colours are kept; points/colors keys accepted."""
    pts = np.arange(12.0).reshape(4, 3)
    u8 = np.array([[0, 128, 255]] * 4, dtype=np.uint8)
    np.savez(tmp_path / "a.npz", verts=pts.astype(np.float32), rgb=u8)
    c = load_pointcloud(tmp_path / "a.npz")
    assert c.points.dtype == np.float64
    np.testing.assert_array_equal(c.features, u8 / 255.0)
    np.savez(tmp_path / "b.npz", points=pts, colors=np.full((4, 3), 0.25))
    np.testing.assert_array_equal(load_pointcloud(tmp_path / "b.npz").features, 0.25)
    np.savez(tmp_path / "g.npz", points=pts, colours=np.array([0, 51, 102, 255], np.uint8))
    np.testing.assert_array_equal(load_pointcloud(tmp_path / "g.npz").features,
                                  [[0.0], [0.2], [0.4], [1.0]])  # one grey channel


def test_pointcloud_ply_round_trip(tmp_path):
    """PLY: positions and normals exact (doubles), colours as 8-bit values."""
    rng = np.random.default_rng(6)
    pts, nrm = rng.normal(size=(40, 3)), rng.normal(size=(40, 3))
    rgb = rng.integers(0, 256, size=(40, 3)) / 255.0
    save_pointcloud(tmp_path / "c.ply", PointCloud(pts, rgb, nrm))
    c = load_pointcloud(tmp_path / "c.ply")
    np.testing.assert_array_equal(c.points, pts)
    np.testing.assert_array_equal(c.normals, nrm)
    np.testing.assert_allclose(c.features, rgb, rtol=0, atol=1e-12)
    save_pointcloud(tmp_path / "p.ply", PointCloud(pts))
    c = load_pointcloud(tmp_path / "p.ply")
    assert c.features is None and c.normals is None
    np.testing.assert_array_equal(c.points, pts)


def test_pointcloud_errors(tmp_path):
    pts = np.zeros((3, 3))
    with pytest.raises(ValueError, match=r"path: expected a \.npz or \.ply file, got 'c\.xyz'"):
        load_pointcloud(tmp_path / "c.xyz")
    with pytest.raises(FileNotFoundError, match=r"point cloud file not found: .*c\.npz"):
        load_pointcloud(tmp_path / "c.npz")
    np.savez(tmp_path / "k.npz", xyz=pts)
    with pytest.raises(ValueError, match=r"k\.npz: expected the points under one of"):
        load_pointcloud(tmp_path / "k.npz")
    np.savez(tmp_path / "s.npz", verts=np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"s\.npz: verts: expected shape \(n, 3\)"):
        load_pointcloud(tmp_path / "s.npz")
    np.savez(tmp_path / "n.npz", verts=np.array([[0, 0, np.nan]]))
    with pytest.raises(ValueError, match=r"n\.npz: verts: expected finite values"):
        load_pointcloud(tmp_path / "n.npz")
    np.savez(tmp_path / "e.npz", verts=np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"e\.npz: the file holds no points"):
        load_pointcloud(tmp_path / "e.npz")
    np.savez(tmp_path / "m.npz", verts=pts, rgb=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"m\.npz: rgb: expected shape \(3, n\), got \(2, 3\)"):
        load_pointcloud(tmp_path / "m.npz")
    np.savez(tmp_path / "i.npz", verts=pts, rgb=np.full((3, 3), 300, dtype=np.int32))
    with pytest.raises(ValueError, match=r"i\.npz: integer colours 'rgb' must lie in \[0, 255\]"):
        load_pointcloud(tmp_path / "i.npz")
    np.savez(tmp_path / "nn.npz", verts=pts, normals=np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"nn\.npz: normals: expected shape \(3, 3\)"):
        load_pointcloud(tmp_path / "nn.npz")
    write(tmp_path / "g.ply", "garbage")
    with pytest.raises(ValueError, match=r"g\.ply: not a PLY file"):
        load_pointcloud(tmp_path / "g.ply")
    cloud = PointCloud(pts, np.zeros((3, 1)))
    with pytest.raises(TypeError, match="cloud: expected a geofit PointCloud"):
        save_pointcloud(tmp_path / "a.npz", pts)
    with pytest.raises(ValueError, match=r"path: expected a \.npz or \.ply file"):
        save_pointcloud(tmp_path / "a.txt", cloud)
    with pytest.raises(ValueError, match="a PLY needs 3 colour channels, got 1"):
        save_pointcloud(tmp_path / "a.ply", cloud)
    with pytest.raises(ValueError, match=r"PLY colours must lie in \[0, 1\]"):
        save_pointcloud(tmp_path / "a.ply", PointCloud(pts, np.full((3, 3), 2.0)))
    with pytest.raises(OSError, match=r"nodir/a\.ply: could not write the file"):
        save_pointcloud(tmp_path / "nodir" / "a.ply", PointCloud(pts))
    assert not (tmp_path / "a.ply").exists()


# --------------------------------------------------------------------------- real tutorial data
COW = geofit.data.find("cow_mesh/cow.obj")


@pytest.mark.skipif(COW is None, reason="tutorial cow not available (set GEOFIT_DATA)")
def test_real_cow_matches_pytorch3d():
    """The tutorial cow: counts, texture size, and PyTorch3D's load_obj arrays exactly."""
    ref = np.load(DATA / "io_cow.npz")
    d = load_obj(COW)
    assert d.verts.shape == (2930, 3) and d.faces.shape == (5856, 3)
    assert d.verts_uvs.shape == (3225, 2) and d.faces_uvs.min() >= 0
    assert d.texture_images["material_1"].shape == (1024, 1024, 3)
    v32 = d.verts.astype(np.float32).astype(np.float64)  # PyTorch3D holds float32 positions
    np.testing.assert_array_equal(v32[:50], ref["verts_first50"])
    np.testing.assert_array_equal(d.faces[:50], ref["faces_first50"])
    np.testing.assert_array_equal(v32.sum(0), ref["verts_sum"])
    np.testing.assert_array_equal(d.faces.sum(0), ref["faces_sum"])
    np.testing.assert_array_equal((d.faces * np.arange(1, 5857)[:, None]).sum(0),
                                  ref["faces_weighted_sum"])
    mesh = load_objs_as_meshes([COW])[0]
    colour = mesh.sample_textures(ref["uvlookup_face"], ref["uvlookup_bary"])
    np.testing.assert_allclose(colour, ref["uvlookup_colour"], rtol=0, atol=1e-4)  # float32 ref


# ------------------------------------------------------------------------ load_mesh / save_mesh
def _coloured_sphere(level=2):
    m = ico_sphere(level)
    cols = np.random.default_rng(7).uniform(0, 1, (m.n_verts, 3))  # like fitted colours
    return Mesh(m.verts, m.faces, TexturesVertex(cols))


@pytest.mark.parametrize("ext, atol", [(".obj", 0.0), (".ply", 0.0), (".off", 1e-9),
                                       (".glb", 1e-6)])
def test_save_mesh_load_mesh_round_trip(tmp_path, ext, atol):
    """save_mesh then load_mesh keeps vertex order and faces (positions to format precision)."""
    mesh = _coloured_sphere()
    save_mesh(tmp_path / f"m{ext}", mesh)
    back = load_mesh(tmp_path / f"m{ext}")
    np.testing.assert_allclose(back.verts, mesh.verts, rtol=0, atol=atol)
    np.testing.assert_array_equal(back.faces, mesh.faces)


@pytest.mark.parametrize("ext", [".ply", ".glb"])
def test_fitted_colours_export_to_ply_and_glb(tmp_path, ext):
    """Vertex colours come back within 1/255 from the 8-bit formats (none on request)."""
    mesh = _coloured_sphere()
    save_mesh(tmp_path / f"fit{ext}", mesh)
    back = load_mesh(tmp_path / f"fit{ext}")
    assert isinstance(back.textures, TexturesVertex)
    err = np.abs(back.textures.verts_features - mesh.textures.verts_features).max()
    assert err <= 1 / 255
    assert load_mesh(tmp_path / f"fit{ext}", load_textures=False).textures is None


def test_stl_vertices_are_merged(tmp_path):
    """An STL triangle soup loads with its shared vertices merged: 2,562 for ico_sphere(4)."""
    mesh = ico_sphere(4)
    save_mesh(tmp_path / "s.stl", mesh)
    back = load_mesh(tmp_path / "s.stl")
    assert (back.n_verts, back.n_faces) == (2562, 5120)
    assert back.topology.is_watertight
    # same triangles up to float32: every face's corners match the original's
    np.testing.assert_allclose(np.sort(back.verts[back.faces].reshape(-1, 9), axis=0),
                               np.sort(mesh.verts[mesh.faces].reshape(-1, 9), axis=0), atol=1e-6)


def test_glb_keeps_uv_texture(tmp_path):
    """A UV-textured mesh (with seams) written as GLB reloads with its per-corner UVs and map."""
    m = geofit.data.procedural_textured_mesh(n_lat=6, n_lon=8, texture_size=16)
    t = m.textures
    mesh = Mesh(m.verts, m.faces, TexturesUV(np.round(t.maps * 255) / 255, t.faces_uvs,
                                             t.verts_uvs))
    back = glb_round_trip(mesh, tmp_path / "t.glb")
    np.testing.assert_array_equal(back.textures.maps, mesh.textures.maps)


def test_obj_texture_round_trip_through_save_mesh(tmp_path):
    """save_mesh(.obj) is save_obj: the UV texture and exact coordinates come back."""
    m = geofit.data.procedural_textured_mesh(n_lat=5, n_lon=6, texture_size=16)
    save_mesh(tmp_path / "t.obj", m)
    back = load_mesh(tmp_path / "t.obj")
    np.testing.assert_array_equal(back.verts, m.verts)
    np.testing.assert_array_equal(back.textures.faces_uvs, m.textures.faces_uvs)


@pytest.mark.parametrize("name, text, faces", [
    ("q.off", "OFF\n5 1 0\n0 0 0\n1 0 0\n1 1 0\n0.5 1.5 0\n0 1 0\n5 0 1 2 3 4\n", 3),
    ("q.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
              "0 0 0 255 0 0\n1 0 0 0 255 0\n1 1 0 0 0 255\n0 1 0 10 20 30\n4 0 1 2 3\n", 2)])
def test_polygons_are_triangulated(tmp_path, name, text, faces):
    """Quads and pentagons load as triangles; PLY colours come along."""
    mesh = load_mesh(write(tmp_path / name, text))
    assert mesh.n_faces == faces
    assert np.isclose(mesh.face_areas.sum(), 1.25 if faces == 3 else 1.0)
    if name.endswith(".ply"):
        np.testing.assert_array_equal(mesh.textures.verts_features[3], np.array([10, 20, 30]) / 255)


def test_save_mesh_accepts_library_meshes(tmp_path):
    """trimesh and Open3D meshes are written as they are."""
    import trimesh

    save_mesh(tmp_path / "box.ply", trimesh.creation.box())
    assert load_mesh(tmp_path / "box.ply").n_faces == 12
    save_obj(tmp_path / "box.obj", ico_sphere(1).to_open3d())
    assert load_mesh(tmp_path / "box.obj").n_verts == 42


def test_wrong_format_errors(tmp_path):
    """Each function refuses what it cannot do and names the format and the right function."""
    mesh = ico_sphere(1)
    save_mesh(tmp_path / "m.ply", mesh)
    with pytest.raises(ValueError,
                       match=r"m\.ply: this is a PLY file, not OBJ.*geofit\.io\.load_mesh"):
        load_obj(tmp_path / "m.ply")
    (tmp_path / "disguised.obj").write_bytes((tmp_path / "m.ply").read_bytes())
    with pytest.raises(ValueError, match=r"disguised\.obj: this is a PLY file"):
        load_obj(tmp_path / "disguised.obj")
    np.testing.assert_array_equal(load_mesh(tmp_path / "disguised.obj").verts, mesh.verts)
    with pytest.raises(ValueError,
                       match=r"save_obj writes Wavefront OBJ.*PLY.*geofit\.io\.save_mesh"):
        save_obj(tmp_path / "x.ply", mesh)
    assert not (tmp_path / "x.ply").exists()
    with pytest.raises(ValueError, match=r"save_mesh writes \.obj, \.ply.*'x\.gltf'.*\.glb"):
        save_mesh(tmp_path / "x.gltf", mesh)
    with pytest.raises(ValueError, match=r"save_mesh writes .*'x\.fbx'"):
        save_mesh(tmp_path / "x.fbx", mesh)
    with pytest.raises(TypeError, match="mesh: expected a geofit Mesh"):
        save_mesh(tmp_path / "x.ply", mesh.verts)
    with pytest.raises(ValueError, match="at least one face"):
        save_mesh(tmp_path / "x.ply", Mesh(np.eye(3), np.zeros((0, 3), np.int64)))
    save_pointcloud(tmp_path / "c.ply", PointCloud(np.eye(3)))
    with pytest.raises(ValueError, match=r"c\.ply: the file has no faces.*load_pointcloud"):
        load_mesh(tmp_path / "c.ply")
    with pytest.raises(ValueError, match=r"\.npz holds a point cloud.*load_pointcloud"):
        load_mesh(tmp_path / "c.npz")
    write(tmp_path / "bad.glb", "not a glb")
    with pytest.raises(ValueError, match=r"bad\.glb: GLB file of 9 bytes is shorter than its "
                                         r"header"):
        load_mesh(tmp_path / "bad.glb")


def test_docstring_examples_run():
    """The examples in geofit.io.mesh and geofit.io.obj docstrings run (doctest)."""
    import doctest

    import geofit.io.mesh as gm
    import geofit.io.obj as go

    for mod in (gm, go):
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0, mod.__name__
        assert result.attempted > 0, mod.__name__


def test_load_mesh_reads_gltf_with_side_files(tmp_path):
    """A .gltf (JSON plus .bin buffers, as trimesh writes it) loads with its vertex colours."""
    import trimesh

    tm = trimesh.creation.icosphere(2)
    tm.visual.vertex_colors = np.tile([200, 10, 10, 255], (len(tm.vertices), 1)).astype(np.uint8)
    for name, blob in trimesh.exchange.gltf.export_gltf(tm.scene()).items():
        (tmp_path / name).write_bytes(blob)
    mesh = load_mesh(tmp_path / "model.gltf")
    assert (mesh.n_verts, mesh.n_faces) == (162, 320)
    np.testing.assert_allclose(mesh.verts, tm.vertices, atol=1e-6)  # float32 in glTF
    np.testing.assert_array_equal(mesh.textures.verts_features,
                                  np.tile([200, 10, 10], (162, 1)) / 255)


def test_ply_bakes_a_uv_texture_into_vertex_colours(tmp_path):
    """A UV-textured mesh saved as PLY carries the texture's colour at each vertex."""
    m = ico_sphere(1)
    uv = np.full((1, 2), 0.5)
    maps = np.broadcast_to([0.2, 0.4, 0.6], (4, 4, 3))  # one colour everywhere
    mesh = Mesh(m.verts, m.faces, TexturesUV(maps, np.zeros_like(m.faces), uv))
    save_mesh(tmp_path / "t.ply", mesh)
    back = load_mesh(tmp_path / "t.ply")
    np.testing.assert_allclose(back.textures.verts_features,
                               np.tile([0.2, 0.4, 0.6], (m.n_verts, 1)), atol=0.5 / 255)
