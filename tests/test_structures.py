"""Mesh, Meshes, PointCloud, Pointclouds and textures: invariants, caches and validation."""
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geofit import (
    Mesh,
    Meshes,
    PointCloud,
    Pointclouds,
    TexturesUV,
    TexturesVertex,
    box,
    ico_sphere,
    plane,
    torus,
)
from geofit._validate import as_array, as_faces, as_rng, check_choice, check_positive

DATA = Path(__file__).parent / "data"


def _slow_edges(faces):
    """Reference: unique sorted edges by a Python set."""
    s = set()
    for f in faces.tolist():
        for a, b in ((f[1], f[2]), (f[2], f[0]), (f[0], f[1])):
            s.add((min(a, b), max(a, b)))
    return np.array(sorted(s))


def test_edges_match_slow_reference_and_faces_to_edges():
    """Unique edges equal a set-based reference; faces_to_edges[f, k] is the edge opposite corner k."""
    m = ico_sphere(2)
    assert_array_equal(m.edges, _slow_edges(m.faces))
    fe = m.topology.faces_to_edges
    e = m.edges[fe]  # (F, 3, 2)
    for k in range(3):
        opp = np.sort(m.faces[:, [(k + 1) % 3, (k + 2) % 3]], axis=1)
        assert_array_equal(e[:, k], opp)


def test_topology_counts_and_euler():
    """An ico-sphere is watertight with V - E + F = 2; a torus has 0; a plane has boundary edges."""
    m = ico_sphere(3)
    t = m.topology
    assert t.is_watertight and t.euler_characteristic == 2
    assert len(m.edges) == 3 * m.n_faces // 2
    assert t.adjacency.nnz == 2 * len(m.edges)
    assert_array_equal(t.degrees, np.asarray(t.adjacency.sum(1)).ravel())
    assert set(np.unique(t.degrees)) == {5, 6}
    assert torus().topology.euler_characteristic == 0
    p = plane(n=3)
    assert not p.topology.is_watertight
    assert len(p.topology.boundary_edges) == 12
    assert_array_equal(np.sort(p.topology.vertex_neighbours(0)), [1, 4, 5])


def test_face_normals_areas_and_vertex_normals_on_sphere():
    """Areas sum to about 4 pi, face normals are unit and outward, vertex normals ~ positions."""
    m = ico_sphere(4)
    assert_allclose(m.face_areas.sum(), 4 * np.pi, rtol=3e-3)
    assert_allclose(np.linalg.norm(m.face_normals, axis=1), 1.0, rtol=1e-12)
    centroids = m.verts[m.faces].mean(1)
    assert np.all(np.einsum("ij,ij->i", m.face_normals, centroids) > 0)
    assert_allclose(np.linalg.norm(m.verts_normals, axis=1), 1.0, rtol=1e-12)
    assert np.min(np.einsum("ij,ij->i", m.verts_normals, m.verts)) > 0.999


def test_areas_converge_under_refinement():
    """Total area of the ico-sphere approaches 4 pi monotonically as the level rises."""
    errs = [abs(ico_sphere(level).face_areas.sum() - 4 * np.pi) for level in range(5)]
    assert all(a > b for a, b in zip(errs, errs[1:]))
    assert errs[-1] < 0.02


def test_degenerate_and_isolated_vertices_give_zero_normals_not_nan():
    """A zero-area face gets a zero normal; an unreferenced vertex gets a zero vertex normal."""
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 5.0]])
    m = Mesh(V, [[0, 1, 2]])
    assert m.face_areas[0] == 0
    assert_array_equal(m.face_normals, 0)
    assert np.all(np.isfinite(m.verts_normals))
    assert_array_equal(m.verts_normals[3], 0)


def test_update_verts_shares_topology_and_recomputes_geometry():
    """update_verts keeps the Topology object and recomputes areas for the new positions."""
    m = ico_sphere(2)
    _ = m.edges
    m2 = m.update_verts(m.verts * 2)
    assert m2.topology is m.topology
    assert_allclose(m2.face_areas, 4 * m.face_areas, rtol=1e-12)
    m3 = m.offset_verts([1.0, 0, 0])
    assert_allclose(m3.verts - m.verts, np.broadcast_to([1.0, 0, 0], m.verts.shape))
    assert_allclose(m.scale_verts(3).verts, 3 * m.verts)


def test_arrays_are_read_only():
    """Cached geometry stays valid because vertex and face arrays cannot be changed in place."""
    m = ico_sphere(1)
    with pytest.raises(ValueError):
        m.verts[0, 0] = 1.0
    with pytest.raises(ValueError):
        m.faces[0, 0] = 1


def test_normalize_round_trip():
    """normalize() centres on the mean, scales max |coord| to 1, and undo restores the input."""
    rng = np.random.default_rng(0)
    m = ico_sphere(2).update_verts(ico_sphere(2).verts * [3, 1, 2] + [5, -1, 2])
    norm = m.normalize()
    assert_allclose(norm.mesh.verts.mean(0), 0, atol=1e-12)
    assert_allclose(np.abs(norm.mesh.verts).max(), 1.0)
    assert_allclose(norm.undo(norm.mesh.verts), m.verts, atol=1e-12)
    with pytest.raises(ValueError, match="coincide"):
        Mesh(np.ones((3, 3)), [[0, 1, 2]]).normalize()
    with pytest.raises(ValueError, match="no vertices"):
        Mesh(np.zeros((0, 3)), np.zeros((0, 3), int)).normalize()
    assert rng is not None


def test_meshes_packed_views_and_extend():
    """Packed faces index packed verts; extend repeats each mesh consecutively (PyTorch3D order)."""
    a, b = ico_sphere(0), box()
    batch = Meshes([a, b])
    assert_array_equal(batch.num_verts_per_mesh(), [12, 8])
    assert_array_equal(batch.mesh_to_faces_packed_first_idx(), [0, 20])
    vp, fp = batch.verts_packed(), batch.faces_packed()
    assert_allclose(vp[fp[20:]], b.verts[b.faces])
    assert_array_equal(batch.faces_packed_to_mesh_idx()[[0, 19, 20, 31]], [0, 0, 1, 1])
    assert batch.verts_padded().shape == (2, 12, 3)
    ext = batch.extend(3)
    assert len(ext) == 6 and ext[0] is a and ext[2] is a and ext[3] is b
    assert len(a.extend(4)) == 4
    moved = batch.offset_verts(np.ones((20, 3)))
    assert_allclose(moved.verts_packed(), vp + 1)
    assert moved[1].topology is b.topology
    sub = ext[2:4]
    assert len(sub) == 2 and sub[1] is b
    assert len(ext[np.array([True, False, False, True, False, False])]) == 2
    m2 = Meshes.from_lists([a.verts, b.verts], [a.faces, b.faces])
    assert_allclose(m2.verts_packed(), vp)


def test_textures_uv_bilinear_sampling_convention():
    """v = 1 is the top row; u, v at pixel centres (align_corners) return those pixels exactly."""
    img = np.arange(4 * 5 * 3, dtype=float).reshape(4, 5, 3) / 60.0
    uvs = np.array([[0.0, 1.0], [1.0, 0.0], [0.25, 2 / 3], [-1.0, 2.0]])
    tex = TexturesUV(img, np.zeros((1, 3), int), uvs)
    s = tex.sample_uv(uvs)
    assert_allclose(s[0], img[0, 0])          # u=0, v=1: top-left
    assert_allclose(s[1], img[3, 4])          # u=1, v=0: bottom-right
    assert_allclose(s[2], img[1, 1])          # x = 0.25*4 = 1, y = (1/3)*3 = 1
    assert_allclose(s[3], img[0, 0])          # border padding clamps
    mid = tex.sample_uv(np.array([[0.125, 1.0]]))  # halfway between columns 0 and 1
    assert_allclose(mid[0], 0.5 * (img[0, 0] + img[0, 1]))
    rep = TexturesUV(img, np.zeros((1, 3), int), uvs, padding_mode="repeat")
    assert_allclose(rep.sample_uv(np.array([[1.25, 2 / 3]])), rep.sample_uv(np.array([[0.25, 2 / 3]])))


def test_textures_on_mesh_and_vertex_colours():
    """sample_textures interpolates per-vertex colours barycentrically and reads UV maps per face."""
    m = Mesh(np.eye(3), [[0, 1, 2]], TexturesVertex(np.eye(3)))
    bary = np.array([[0.2, 0.3, 0.5]])
    assert_allclose(m.sample_textures(np.array([0]), bary), bary)
    img = np.zeros((2, 2, 3))
    img[0, 0] = 1.0  # top-left texel
    tex = TexturesUV(img, [[0, 1, 2]], [[0, 1], [0, 1], [0, 1]])
    m2 = Mesh(np.eye(3), [[0, 1, 2]], tex)
    assert_allclose(m2.sample_textures(np.array([0]), bary), [[1, 1, 1]])
    with pytest.raises(ValueError, match="no textures"):
        Mesh(np.eye(3), [[0, 1, 2]]).sample_textures(np.array([0]), bary)


def test_pointclouds_batch():
    """Packed and padded point views, features, extend and subsample reproducibility."""
    rng = np.random.default_rng(1)
    a = PointCloud(rng.random((5, 3)), rng.random((5, 3)))
    b = PointCloud(rng.random((3, 3)), rng.random((3, 3)))
    pcs = Pointclouds([a, b])
    assert_array_equal(pcs.num_points_per_cloud(), [5, 3])
    assert_array_equal(pcs.cloud_to_packed_first_idx(), [0, 5])
    assert pcs.points_packed().shape == (8, 3) and pcs.features_packed().shape == (8, 3)
    assert pcs.points_padded().shape == (2, 5, 3)
    assert len(pcs.extend(2)) == 4
    assert_array_equal(a.subsample(3, seed=4).points, a.subsample(3, seed=4).points)
    assert PointCloud(np.zeros((0, 3))).isempty()
    assert Pointclouds([PointCloud(np.zeros((2, 3)))]).features_packed() is None


# ---------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "verts, faces, match",
    [
        (np.zeros((3, 2)), [[0, 1, 2]], r"verts: expected shape \(n, 3\), got \(3, 2\)"),
        ([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], "verts: expected finite"),
        (np.eye(3), [[0, 1, 3]], r"faces: vertex indices must lie in \[0, 2\]"),
        (np.eye(3), [[0, -1, 2]], r"faces: vertex indices must lie in \[0, 2\]"),
        (np.eye(3), [[0, 1]], r"faces: expected shape \(n, 3\), got \(1, 2\)"),
        (np.eye(3), [[0, 1, 1.5]], "faces: expected integer indices, got fractional"),
        (np.eye(3), [["a", "b", "c"]], "faces: expected integers"),
        ([[1, 2], [3]], [[0, 1, 2]], "verts: "),
    ],
)
def test_mesh_validation(verts, faces, match):
    with pytest.raises(ValueError, match=match):
        Mesh(verts, faces)


def test_texture_and_batch_validation():
    with pytest.raises(ValueError, match="textures.faces_uvs"):
        Mesh(np.eye(3), [[0, 1, 2]], TexturesUV(np.zeros((2, 2, 3)), [[0, 0, 0], [0, 0, 0]], [[0, 0]]))
    with pytest.raises(ValueError, match="textures.verts_features"):
        Mesh(np.eye(3), [[0, 1, 2]], TexturesVertex(np.zeros((2, 3))))
    with pytest.raises(TypeError, match="textures"):
        Mesh(np.eye(3), [[0, 1, 2]], textures="red")
    with pytest.raises(ValueError, match="maps: expected a non-empty"):
        TexturesUV(np.zeros((0, 2, 3)), [[0, 0, 0]], [[0, 0]])
    with pytest.raises(ValueError, match="faces_uvs: vertex indices"):
        TexturesUV(np.zeros((2, 2, 3)), [[0, 0, 5]], [[0, 0]])
    with pytest.raises(ValueError, match="padding_mode"):
        TexturesUV(np.zeros((2, 2, 3)), [[0, 0, 0]], [[0, 0]], padding_mode="zeros")
    with pytest.raises(ValueError, match="verts_uvs"):
        TexturesUV(np.zeros((2, 2, 3)), [[0, 0, 0]], [[0, 0, 0]])
    with pytest.raises(TypeError, match=r"meshes\[1\]"):
        Meshes([ico_sphere(0), "x"])
    with pytest.raises(ValueError, match="n: expected an integer >= 1"):
        Meshes([ico_sphere(0)]).extend(0)
    with pytest.raises(ValueError, match="faces: expected 1 face arrays"):
        Meshes.from_lists([np.eye(3)], [])
    with pytest.raises(ValueError, match="textures: expected 1 entries"):
        Meshes.from_lists([np.eye(3)], [[[0, 1, 2]]], textures=[])
    with pytest.raises(ValueError, match=r"offsets: expected shape \(12, 3\)"):
        ico_sphere(0).offset_verts(np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"verts: expected shape \(12, 3\)"):
        ico_sphere(0).update_verts(np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"verts_packed: expected shape \(12, 3\)"):
        Meshes([ico_sphere(0)]).update_packed(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="scale: expected a finite"):
        ico_sphere(0).scale_verts(np.inf)


def test_pointcloud_validation():
    with pytest.raises(ValueError, match=r"points: expected shape \(n, 3\)"):
        PointCloud(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"features: expected shape \(4, n\)"):
        PointCloud(np.zeros((4, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"normals: expected shape \(4, 3\)"):
        PointCloud(np.zeros((4, 3)), normals=np.zeros((4, 2)))
    with pytest.raises(ValueError, match="points: expected finite"):
        PointCloud([[0, 0, np.inf]])
    with pytest.raises(ValueError, match="either every cloud has features"):
        Pointclouds([PointCloud(np.zeros((1, 3)), np.zeros((1, 3))), PointCloud(np.zeros((1, 3)))])
    with pytest.raises(ValueError, match="channel counts differ"):
        Pointclouds([PointCloud(np.zeros((1, 3)), np.zeros((1, 3))),
                     PointCloud(np.zeros((1, 3)), np.zeros((1, 4)))])
    with pytest.raises(TypeError, match=r"clouds\[0\]"):
        Pointclouds([np.zeros((2, 3))])
    with pytest.raises(ValueError, match="features: expected 1 arrays"):
        Pointclouds.from_lists([np.zeros((1, 3))], [])


def test_validate_helpers():
    with pytest.raises(ValueError, match="x: expected a non-empty array"):
        as_array(np.zeros((0, 3)), "x", (None, 3), allow_empty=False)
    with pytest.raises(ValueError, match="x: expected real numbers"):
        as_array(np.array(["a"]), "x")
    with pytest.raises(ValueError, match="f: expected integer indices, got non-finite"):
        as_faces(np.array([[0, 1, np.nan]]), "f", 3)
    with pytest.raises(TypeError, match="seed"):
        as_rng("seed")
    with pytest.raises(ValueError, match=r"mode: expected one of \('a', 'b'\)"):
        check_choice("c", "mode", ("a", "b"))
    with pytest.raises(ValueError, match="r: expected a finite number > 0"):
        check_positive(0.0, "r")
    with pytest.raises(ValueError, match="r: expected a finite number >= 0"):
        check_positive(-1.0, "r", strict=False)
    with pytest.raises(ValueError, match="r: expected a number"):
        check_positive("x", "r")
    g = np.random.default_rng(3)
    assert as_rng(g) is g
    assert_array_equal(as_rng(5).random(3), np.random.default_rng(5).random(3))


def test_open3d_conversions_copy_read_only_arrays():
    """to_open3d works on read-only arrays and keeps positions, faces, colours and normals."""
    m = Mesh(np.eye(3), [[0, 1, 2]], TexturesVertex(np.full((3, 3), 0.5)))
    o = m.to_open3d()
    assert_allclose(np.asarray(o.vertices), m.verts)
    assert_array_equal(np.asarray(o.triangles), m.faces)
    assert_allclose(np.asarray(o.vertex_colors), 0.5)
    pc = PointCloud(np.eye(3), np.full((3, 3), 0.25), normals=np.eye(3)).to_open3d()
    assert_allclose(np.asarray(pc.points), np.eye(3))
    assert_allclose(np.asarray(pc.colors), 0.25)
    assert_allclose(np.asarray(pc.normals), np.eye(3))


# ----------------------------------------------------------------------------- trimesh / Open3D
def _seamed_mesh():
    """A UV-mapped mesh with seams (faces_uvs != faces) and an 8-bit texture map."""
    from geofit.data import procedural_textured_mesh

    m = procedural_textured_mesh(n_lat=6, n_lon=8, texture_size=16)
    t = m.textures  # maps read from image files hold multiples of 1/255; Open3D keeps 8 bits
    maps = np.round(t.maps * 255) / 255
    return Mesh(m.verts, m.faces, TexturesUV(maps, t.faces_uvs, t.verts_uvs))


def _assert_same_mesh(a, b):
    assert_array_equal(a.verts, b.verts)
    assert_array_equal(a.faces, b.faces)
    assert type(a.textures) is type(b.textures)
    if isinstance(a.textures, TexturesVertex):
        assert_array_equal(a.textures.verts_features, b.textures.verts_features)
    elif isinstance(a.textures, TexturesUV):
        assert_array_equal(a.textures.verts_uvs[a.textures.faces_uvs],
                           b.textures.verts_uvs[b.textures.faces_uvs])
        assert_array_equal(a.textures.maps, b.textures.maps)


@pytest.mark.parametrize("lib", ["trimesh", "open3d"])
def test_mesh_round_trip_keeps_uvs_exactly(lib):
    """Mesh -> trimesh/Open3D -> Mesh keeps vertices, faces, per-corner UVs and map exactly."""
    mesh = _seamed_mesh()
    assert not np.array_equal(mesh.textures.faces_uvs, mesh.faces)  # there are seams
    back = (Mesh.from_trimesh(mesh.to_trimesh()) if lib == "trimesh"
            else Mesh.from_open3d(mesh.to_open3d()))
    _assert_same_mesh(mesh, back)
    if lib == "trimesh":  # the seam record gives back the UV table itself, and float maps
        assert_array_equal(back.textures.verts_uvs, mesh.textures.verts_uvs)
        assert_array_equal(back.textures.faces_uvs, mesh.textures.faces_uvs)
        t = mesh.textures
        floaty = Mesh(mesh.verts, mesh.faces, TexturesUV(t.maps * 0.999, t.faces_uvs, t.verts_uvs))
        assert_array_equal(Mesh.from_trimesh(floaty.to_trimesh()).textures.maps, t.maps * 0.999)


@pytest.mark.parametrize("lib", ["trimesh", "open3d"])
def test_mesh_round_trip_keeps_float_colours_exactly(lib):
    """Fitted (unquantised) vertex colours survive the trip exactly."""
    m = ico_sphere(2)
    cols = np.random.default_rng(3).uniform(0, 1, (m.n_verts, 3))
    mesh = Mesh(m.verts, m.faces, TexturesVertex(cols))
    back = (Mesh.from_trimesh(mesh.to_trimesh()) if lib == "trimesh"
            else Mesh.from_open3d(mesh.to_open3d()))
    _assert_same_mesh(mesh, back)


def test_trimesh_to_mesh_and_back_exactly():
    """trimesh -> Mesh -> trimesh keeps vertices, faces, 8-bit colours, and UVs with the image."""
    import trimesh
    from PIL import Image

    tm = trimesh.creation.icosphere(2)
    rgba = np.random.default_rng(0).integers(0, 256, (len(tm.vertices), 4)).astype(np.uint8)
    tm.visual.vertex_colors = rgba
    back = Mesh.from_trimesh(tm).to_trimesh()
    assert_array_equal(back.vertices, tm.vertices)
    assert_array_equal(back.faces, tm.faces)
    assert_array_equal(back.visual.vertex_colors, rgba)

    uv = np.random.default_rng(1).uniform(0, 1, (len(tm.vertices), 2))
    img = np.random.default_rng(2).integers(0, 256, (8, 12, 3)).astype(np.uint8)
    tt = trimesh.Trimesh(tm.vertices, tm.faces, process=False,
                         visual=trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(img)))
    mesh = Mesh.from_trimesh(tt)
    assert_array_equal(mesh.textures.faces_uvs, mesh.faces)
    assert_array_equal(mesh.textures.maps, img / 255.0)
    back = mesh.to_trimesh()
    assert_array_equal(back.vertices, tm.vertices)
    assert_array_equal(back.faces, tm.faces)
    assert_array_equal(back.visual.uv, uv)
    assert_array_equal(np.asarray(back.visual.material.image), img)


def test_open3d_to_mesh_and_back_exactly():
    """Open3D -> Mesh -> Open3D keeps vertices, triangles, colours and per-corner UVs."""
    import open3d as o3d

    o = o3d.geometry.TriangleMesh.create_sphere(0.5, 6)
    cols = np.random.default_rng(0).uniform(0, 1, (len(o.vertices), 3))
    o.vertex_colors = o3d.utility.Vector3dVector(cols)
    back = Mesh.from_open3d(o).to_open3d()
    assert_array_equal(np.asarray(back.vertices), np.asarray(o.vertices))
    assert_array_equal(np.asarray(back.triangles), np.asarray(o.triangles))
    assert_array_equal(np.asarray(back.vertex_colors), cols)
    o2 = o3d.geometry.TriangleMesh(o.vertices, o.triangles)
    tri_uv = np.random.default_rng(1).uniform(0, 1, (3 * len(o.triangles), 2))
    o2.triangle_uvs = o3d.utility.Vector2dVector(tri_uv)
    img = np.random.default_rng(2).integers(0, 256, (8, 8, 3)).astype(np.uint8)
    o2.textures = [o3d.geometry.Image(img)]
    back = Mesh.from_open3d(o2).to_open3d()
    assert_array_equal(np.asarray(back.triangle_uvs), tri_uv)
    assert_array_equal(np.asarray(back.textures[0]), img)


@pytest.mark.parametrize("lib", ["trimesh", "open3d"])
def test_pointcloud_round_trip_exact(lib):
    """PointCloud -> trimesh/Open3D -> PointCloud keeps points, float colours and normals."""
    rng = np.random.default_rng(4)
    pc = PointCloud(rng.normal(size=(50, 3)), rng.uniform(0, 1, (50, 3)), rng.normal(size=(50, 3)))
    back = (PointCloud.from_trimesh(pc.to_trimesh()) if lib == "trimesh"
            else PointCloud.from_open3d(pc.to_open3d()))
    assert_array_equal(back.points, pc.points)
    assert_array_equal(back.features, pc.features)
    assert_array_equal(back.normals, pc.normals)


def test_foreign_pointclouds_to_pointcloud_and_back():
    """trimesh/Open3D clouds -> PointCloud -> same library keeps points and colours."""
    import open3d as o3d
    import trimesh

    rng = np.random.default_rng(5)
    pts = rng.normal(size=(30, 3))
    rgba = rng.integers(0, 256, (30, 4)).astype(np.uint8)
    rgba[:, 3] = 255
    tc = trimesh.PointCloud(pts, colors=rgba)
    back = PointCloud.from_trimesh(tc).to_trimesh()
    assert_array_equal(back.vertices, pts)
    assert_array_equal(back.colors, rgba)
    oc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    oc.colors = o3d.utility.Vector3dVector(rgba[:, :3] / 255.0)
    back = PointCloud.from_open3d(oc).to_open3d()
    assert_array_equal(np.asarray(back.points), pts)
    assert_array_equal(np.asarray(back.colors), rgba[:, :3] / 255.0)


def test_stale_trimesh_record_is_ignored():
    """Colours edited on the trimesh side win over the record to_trimesh left in metadata."""
    m = ico_sphere(1)
    mesh = Mesh(m.verts, m.faces, TexturesVertex(np.full((m.n_verts, 3), 0.3)))
    tm = mesh.to_trimesh()
    tm.visual.vertex_colors = np.tile([255, 0, 0, 255], (m.n_verts, 1)).astype(np.uint8)
    assert_array_equal(Mesh.from_trimesh(tm).textures.verts_features,
                       np.tile([1.0, 0.0, 0.0], (m.n_verts, 1)))


def test_as_mesh_and_as_pointcloud_accept_foreign_and_reject_others():
    """The coercion helpers convert trimesh/Open3D objects and name what they accept."""
    import open3d as o3d
    import trimesh

    from geofit.structures import as_mesh, as_meshes, as_pointcloud, as_pointclouds

    box_tm = trimesh.creation.box()
    assert as_mesh(box_tm).n_faces == 12
    assert as_mesh(box_tm.scene()).n_faces == 12
    assert as_mesh(o3d.geometry.TriangleMesh.create_box()).n_faces == 12
    assert len(as_meshes([box_tm, ico_sphere(1)])) == 2
    assert len(as_pointcloud(trimesh.PointCloud(np.eye(3)))) == 3
    assert len(as_pointclouds(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3))))) == 1
    with pytest.raises(TypeError, match="target: expected a geofit Mesh, trimesh.Trimesh"):
        as_mesh(np.eye(3), "target")
    with pytest.raises(TypeError, match="cloud: expected a geofit PointCloud"):
        as_pointcloud(box_tm)
    with pytest.raises(TypeError, match="meshes: expected a Mesh or Meshes"):
        as_meshes("cow.obj")
    with pytest.raises(TypeError, match="expected a trimesh.Trimesh"):
        Mesh.from_trimesh(o3d.geometry.TriangleMesh())
    with pytest.raises(TypeError, match="expected an open3d.geometry.TriangleMesh"):
        Mesh.from_open3d(box_tm)
    with pytest.raises(TypeError, match="expected a trimesh.PointCloud"):
        PointCloud.from_trimesh(box_tm)
    with pytest.raises(TypeError, match="expected an open3d.geometry.PointCloud"):
        PointCloud.from_open3d(box_tm)


@pytest.mark.parametrize("kind, hint", [
    ("trimesh", "Mesh.from_trimesh"), ("trimesh_cloud", "cloud.vertices"),
    ("open3d", "numpy.asarray\\(mesh.vertices\\)"),
    ("open3d_cloud", "numpy.asarray\\(cloud.points\\)"),
    ("geofit", "mesh.verts")])
def test_as_array_says_how_to_convert_geometry_objects(kind, hint):
    """A mesh or cloud object where an array is expected gets a TypeError with the conversion."""
    import open3d as o3d
    import trimesh

    obj = {"trimesh": lambda: trimesh.creation.box(),
           "trimesh_cloud": lambda: trimesh.PointCloud(np.eye(3)),
           "open3d": lambda: o3d.geometry.TriangleMesh.create_box(),
           "open3d_cloud": lambda: o3d.geometry.PointCloud(),
           "geofit": lambda: ico_sphere(0)}[kind]()
    with pytest.raises(TypeError, match=f"verts: expected an array, got a .*; .*{hint}"):
        as_array(obj, "verts", (None, 3))


def test_library_meshes_accepted_at_public_boundaries():
    """trimesh and Open3D objects give the same results as the geofit Mesh they convert to."""
    import open3d as o3d
    import trimesh

    from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    from geofit.loss import chamfer_distance, mesh_laplacian_smoothing
    from geofit.metrics import evaluate_mesh
    from geofit.ops import sample_points_from_meshes
    from geofit.raycast import RayCaster
    from geofit.render import MeshRasterizer, RasterizationSettings

    mesh = torus(0.6, 0.25, 12, 8)
    tm, om = mesh.to_trimesh(), mesh.to_open3d()
    R, T = look_at_view_transform(3.0, 20.0, 30.0)
    rast = MeshRasterizer(FoVPerspectiveCameras(R=R, T=T), RasterizationSettings(image_size=16))
    ref = rast(mesh).pix_to_face
    rays_o, rays_d = np.array([[0.0, 0.0, 3.0]]), np.array([[0.0, 0.0, -1.0]])
    from geofit.render.soft import SoftRasterizationSettings, rasterize_soft

    soft = rasterize_soft(mesh, rast.cameras, SoftRasterizationSettings.tutorial(16))
    for obj in (tm, om):
        assert_array_equal(rast(obj).pix_to_face, ref)
        assert_array_equal(rasterize_soft(obj, rast.cameras,
                                          SoftRasterizationSettings.tutorial(16)).dist, soft.dist)
        assert_array_equal(RayCaster(obj).cast(rays_o, rays_d).face_id,
                           RayCaster(mesh).cast(rays_o, rays_d).face_id)
        assert_allclose(mesh_laplacian_smoothing(obj)[0], mesh_laplacian_smoothing(mesh)[0])
        assert_array_equal(sample_points_from_meshes(obj, 20, seed=1),
                           sample_points_from_meshes(mesh, 20, seed=1))
        assert evaluate_mesh(obj, mesh, n_samples=2000).chamfer_l2 < 1e-20
    pts = np.array(mesh.verts)
    oc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    assert chamfer_distance(oc, trimesh.PointCloud(pts)).loss == 0.0
    from geofit.render import PointsRasterizationSettings, PointsRasterizer

    prast = PointsRasterizer(rast.cameras, PointsRasterizationSettings(16, 0.05, 4))
    ref = prast(PointCloud(pts)).idx
    assert (ref >= 0).any()
    for cloud in (oc, trimesh.PointCloud(pts), [oc]):
        assert_array_equal(prast(cloud).idx, ref)


def test_fit_mesh_takes_library_meshes():
    """fit_mesh accepts a trimesh target and an Open3D source (converted at the boundary)."""
    import trimesh

    from geofit.fit import MeshFitOptions, fit_mesh

    target = trimesh.creation.icosphere(2, radius=0.8)
    source = ico_sphere(1).to_open3d()
    res = fit_mesh(target, recipe="sphere",
                   options=MeshFitOptions(init=source, n_samples=300, n_stages=1, n_iter=5),
                   progress=False)
    assert res.mesh.n_verts == 42
    with pytest.raises(TypeError, match="target: expected a geofit Mesh, trimesh.Trimesh"):
        fit_mesh("sphere.obj", recipe="sphere", options=MeshFitOptions(init=source, n_iter=1),
                 progress=False)


def test_docstring_examples_run():
    """The examples in the structures' docstrings run (doctest)."""
    import doctest

    import geofit.structures.mesh as sm

    result = doctest.testmod(sm, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted > 0


def test_trimesh_face_colours_become_vertex_colours():
    """Face colours (which TexturesVertex cannot hold) arrive as the mean over a vertex's faces."""
    import trimesh

    tm = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]],
                         process=False)
    tm.visual.face_colors = [[255, 0, 0, 255], [0, 0, 255, 255]]
    cols = Mesh.from_trimesh(tm).textures.verts_features
    assert_array_equal(cols, [[1, 0, 0], [0.5, 0, 0.5], [0.5, 0, 0.5], [0, 0, 1]])


def test_topology_edge_faces_lists_each_edges_faces():
    """Two triangles sharing the edge (1, 2): that edge has faces 0 and 1, the four boundary
    edges one face and -1; every listed face really has the edge."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    F = np.array([[0, 1, 2], [1, 3, 2]], np.int64)
    topo = Mesh(V, F).topology
    ef = topo.edge_faces
    shared = [i for i, e in enumerate(topo.edges.tolist()) if e == [1, 2]]
    assert len(shared) == 1
    assert_array_equal(ef[shared[0]], [0, 1])
    assert (ef[:, 1] == -1).sum() == 4 and (ef[:, 0] >= 0).all()
    for e, (f0, f1) in zip(topo.edges, ef):
        for f in (f0, f1):
            if f >= 0:
                assert set(e) <= set(F[f])
