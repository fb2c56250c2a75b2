"""Surface sampling: reproducibility, exact Jacobian, points on the surface, uniform area density."""
import numpy as np
import pytest
import scipy.sparse as sp
from numpy.testing import assert_allclose, assert_array_equal
from scipy.stats import chi2

from geofit import Mesh, Meshes, TexturesUV, TexturesVertex, box, ico_sphere, plane
from geofit.ops import (
    PointsNormals,
    PointsNormalsTextures,
    PointsTextures,
    SampledPoints,
    barycentric_matrix,
    sample_points_from_meshes,
    sample_points_with_jacobian,
)


def torus():
    from geofit import torus as _t

    return _t(1.0, 0.3, 16, 8)


def _points_from(verts, faces, face_idx, bary):
    """Reference: the barycentric combination written out per corner."""
    t = verts[faces[face_idx]]
    return bary[:, :1] * t[:, 0] + bary[:, 1:2] * t[:, 1] + bary[:, 2:] * t[:, 2]


def test_seed_reproducible_and_seeds_differ():
    """The same int seed (or an equally seeded Generator) gives identical samples; another differs."""
    m = ico_sphere(2)
    a = sample_points_with_jacobian(m, 500, seed=7, return_normals=True)
    b = sample_points_with_jacobian(m, 500, seed=np.random.default_rng(7), return_normals=True)
    c = sample_points_with_jacobian(m, 500, seed=8)
    assert isinstance(a, SampledPoints)
    assert_array_equal(a.points, b.points)
    assert_array_equal(a.face_idx, b.face_idx)
    assert_array_equal(a.normals, b.normals)
    assert not np.array_equal(a.points, c.points)


def test_shapes_dtypes_and_B_reproduces_points():
    """points == B @ verts; B has three barycentric weights per row, summing to one."""
    m = torus()
    s = sample_points_with_jacobian(m, 2000, seed=0)
    assert s.points.shape == (2000, 3) and s.points.dtype == np.float64
    assert s.face_idx.dtype == np.int64 and s.bary.shape == (2000, 3)
    assert s.normals is None and s.textures is None
    assert sp.isspmatrix_csr(s.B) and s.B.shape == (2000, m.n_verts)
    assert_array_equal(np.diff(s.B.indptr), 3)
    assert_allclose(np.asarray(s.B.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-15)
    assert_allclose(s.points, s.B @ m.verts, rtol=0, atol=1e-15)
    assert_allclose(s.points, _points_from(m.verts, m.faces, s.face_idx, s.bary), rtol=0, atol=1e-15)
    assert np.all(s.bary >= 0) and np.all(s.bary <= 1)
    assert_allclose(s.bary.sum(1), 1.0, rtol=0, atol=1e-15)


def test_B_is_the_finite_difference_jacobian():
    """Central differences of the points w.r.t. every vertex coordinate equal B (fixed faces/bary)."""
    m = box((1.0, 2.0, 0.5))
    s = sample_points_with_jacobian(m, 40, seed=3)
    V = m.verts.copy()
    h = 1e-6
    J = np.zeros((40 * 3, V.size))
    for k in range(V.size):  # loop over the 24 coordinates of a tiny test mesh
        e = np.zeros(V.size)
        e[k] = h
        Vp = V + e.reshape(V.shape)
        Vm = V - e.reshape(V.shape)
        J[:, k] = (_points_from(Vp, m.faces, s.face_idx, s.bary)
                   - _points_from(Vm, m.faces, s.face_idx, s.bary)).ravel() / (2 * h)
    J_B = sp.kron(s.B, sp.identity(3)).toarray()  # d vec(P) / d vec(V) in row-major order
    assert_allclose(J, J_B, rtol=0, atol=1e-9)
    # and the VJP used by fitting: dL/dV = B^T dL/dP for L = <G, P>
    G = np.random.default_rng(0).normal(size=(40, 3))
    assert_allclose((J.T @ G.ravel()).reshape(V.shape), s.B.T @ G, rtol=0, atol=1e-8)


def test_points_lie_on_the_surface():
    """Every sample is within ~1e-12 of the surface (exact closest point) and of its own face's plane."""
    from geofit.raycast import PointToMeshDistance

    m = ico_sphere(3)
    s = sample_points_with_jacobian(m, 3000, seed=1, return_normals=True)
    d = PointToMeshDistance(m).query(s.points).distances
    assert d.max() < 1e-12
    v0 = m.verts[m.faces[s.face_idx, 0]]
    plane_dist = np.abs(np.einsum("ij,ij->i", s.points - v0, m.face_normals[s.face_idx]))
    assert plane_dist.max() < 1e-14


def test_normals_are_unit_face_normals_pointing_out():
    """Returned normals are the sampled faces' unit normals; on a sphere they point outwards."""
    m = ico_sphere(2)
    s = sample_points_with_jacobian(m, 1000, seed=2, return_normals=True)
    assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, rtol=0, atol=1e-14)
    assert_array_equal(s.normals, m.face_normals[s.face_idx])
    assert np.all(np.einsum("ij,ij->i", s.normals, s.points) > 0.9)


def test_face_choice_follows_area_ratio_1_to_3():
    """Chi-square: on two faces with areas 1 and 3 the counts follow 1:3 (p > 0.001 at a fixed seed)."""
    verts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 5], [3, 0, 5], [0, 1, 5]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    m = Mesh(verts, faces)
    assert_allclose(m.face_areas, [0.5, 1.5])
    n = 40000
    s = sample_points_with_jacobian(m, n, seed=11)
    counts = np.bincount(s.face_idx, minlength=2)
    expected = n * np.array([0.25, 0.75])
    stat = np.sum((counts - expected) ** 2 / expected)
    assert stat < chi2.ppf(0.999, df=1), (counts, stat)
    # a uniform (area-blind) face choice would be rejected by the same test
    wrong = n * np.array([0.5, 0.5])
    assert np.sum((counts - wrong) ** 2 / wrong) > chi2.ppf(0.999, df=1)


def test_uniform_density_inside_a_face():
    """Chi-square over the 16 sub-triangles of a twice-subdivided triangle: equal counts."""
    m = Mesh(np.array([[0.0, 0, 0], [2, 0, 0], [0.5, 1.5, 0]]), [[0, 1, 2]])
    n = 32000
    s = sample_points_with_jacobian(m, n, seed=5)
    # sub-triangle index from barycentrics on a 4x4 grid: cell (i, j) of w1, w2 and its parity
    g = 4
    a = s.bary[:, 1] * g
    b = s.bary[:, 2] * g
    i = np.minimum(np.floor(a), g - 1)
    j = np.minimum(np.floor(b), g - 1)
    upper = (a - i) + (b - j) > 1
    cell = (i * g + j) * 2 + upper
    counts = np.bincount(cell.astype(int), minlength=2 * g * g)
    valid = (np.arange(g)[:, None] + np.arange(g)[None, :]).ravel()
    # lower triangles exist for i + j <= g - 1, upper for i + j <= g - 2
    mask = np.stack([valid <= g - 1, valid <= g - 2], axis=1).ravel()
    assert counts[~mask].sum() == 0
    obs = counts[mask]
    assert len(obs) == g * g
    exp = n / (g * g)
    stat = np.sum((obs - exp) ** 2 / exp)
    assert stat < chi2.ppf(0.999, df=g * g - 1), stat
    # the naive (u, v) -> (1 - u - v) mapping without the sqrt warp would fail: check the warp
    # matters by applying the test to un-warped weights
    u = np.random.default_rng(5).random((2, n))
    naive = np.stack([1 - u[0], u[0] * (1 - u[1]), u[0] * u[1]], 1)
    a2, b2 = naive[:, 1] * g, naive[:, 2] * g
    i2, j2 = np.minimum(np.floor(a2), g - 1), np.minimum(np.floor(b2), g - 1)
    cell2 = ((i2 * g + j2) * 2 + ((a2 - i2) + (b2 - j2) > 1)).astype(int)
    obs2 = np.bincount(cell2, minlength=2 * g * g)[mask]
    assert np.sum((obs2 - exp) ** 2 / exp) > chi2.ppf(0.999, df=g * g - 1)


def test_zero_area_faces_are_never_sampled():
    """Degenerate faces (repeated or collinear vertices) get no samples."""
    verts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]])
    faces = np.array([[0, 1, 3], [0, 1, 2], [1, 1, 2]])
    s = sample_points_with_jacobian(Mesh(verts, faces), 5000, seed=0)
    assert_array_equal(np.unique(s.face_idx), [1])


def test_vertex_textures_interpolate_linearly():
    """TexturesVertex colours equal to the positions give colours equal to the sample points."""
    m0 = ico_sphere(1)
    m = Mesh(m0.verts, m0.faces, TexturesVertex(m0.verts))
    s = sample_points_with_jacobian(m, 300, seed=4, return_textures=True)
    assert s.textures.shape == (300, 3)
    assert_allclose(s.textures, s.points, rtol=0, atol=1e-15)


def test_uv_textures_linear_image():
    """A UV map whose value is u (align_corners) colours each plane sample with its x coordinate."""
    p = plane(size=1.0, n=3)
    verts = p.verts + [0.5, 0.5, 0.0]  # [0, 1]^2
    W, H = 9, 5
    img = np.broadcast_to(np.linspace(0, 1, W)[None, :, None], (H, W, 1))
    tex = TexturesUV(img, p.faces, verts[:, :2])
    m = Mesh(verts, p.faces, tex)
    s = sample_points_with_jacobian(m, 500, seed=9, return_textures=True)
    assert_allclose(s.textures[:, 0], s.points[:, 0], rtol=0, atol=1e-12)


def test_meshes_batch_gives_one_result_per_mesh():
    """A Meshes batch returns a list whose B matrices address each mesh's own vertices."""
    batch = Meshes([ico_sphere(1), box()])
    out = sample_points_with_jacobian(batch, 100, seed=0, return_normals=True)
    assert isinstance(out, list) and len(out) == 2
    for s, m in zip(out, batch):
        assert s.B.shape == (100, m.n_verts)
        assert_allclose(s.points, s.B @ m.verts, rtol=0, atol=1e-15)
    again = sample_points_with_jacobian(batch, 100, seed=0)
    assert_array_equal(again[1].points, out[1].points)


def test_barycentric_matrix_public_helper():
    """barycentric_matrix builds the same map for given faces and weights."""
    m = ico_sphere(0)
    fi = np.array([0, 5, 5, 19])
    w = np.array([[1.0, 0, 0], [0.2, 0.3, 0.5], [0, 0, 1], [1 / 3, 1 / 3, 1 / 3]])
    B = barycentric_matrix(m.faces, fi, w, m.n_verts)
    assert_allclose(B @ m.verts, _points_from(m.verts, m.faces, fi, w), rtol=0, atol=1e-15)


def test_pytorch3d_return_values():
    """sample_points_from_meshes returns PyTorch3D's values: points, or (points, normals[, textures])."""
    m0 = ico_sphere(1)
    m = Mesh(m0.verts, m0.faces, TexturesVertex(m0.verts))
    full = sample_points_with_jacobian(m, 200, seed=3, return_normals=True, return_textures=True)
    points = sample_points_from_meshes(m, 200, seed=3)
    assert isinstance(points, np.ndarray) and points.shape == (200, 3)
    assert_array_equal(points, full.points)  # same seed, same samples
    p, n = sample_points_from_meshes(m, 200, seed=3, return_normals=True)
    assert_array_equal(p, full.points)
    assert_array_equal(n, full.normals)
    out = sample_points_from_meshes(m, 200, seed=3, return_textures=True)
    assert isinstance(out, PointsTextures) and len(out) == 2
    assert_array_equal(out.textures, full.textures)
    p, n, t = sample_points_from_meshes(m, 200, seed=3, return_normals=True, return_textures=True)
    assert_array_equal(t, full.textures)
    both = sample_points_from_meshes(m, 200, seed=3, return_normals=True, return_textures=True)
    assert isinstance(both, PointsNormalsTextures)
    assert isinstance(sample_points_from_meshes(m, 5, seed=0, return_normals=True), PointsNormals)


def test_pytorch3d_batch_is_stacked():
    """A Meshes batch gives (N, n, 3) points (and normals, textures), as PyTorch3D's tensors."""
    batch = Meshes([ico_sphere(1), box()])
    per_mesh = sample_points_with_jacobian(batch, 100, seed=0, return_normals=True)
    points, normals = sample_points_from_meshes(batch, 100, seed=0, return_normals=True)
    assert points.shape == (2, 100, 3) and normals.shape == (2, 100, 3)
    for i, s in enumerate(per_mesh):
        assert_array_equal(points[i], s.points)
        assert_array_equal(normals[i], s.normals)
    assert sample_points_from_meshes(batch, 7, seed=0).shape == (2, 7, 3)
    # textures of different channel counts cannot be stacked
    a = Mesh(ico_sphere(0).verts, ico_sphere(0).faces, TexturesVertex(np.ones((12, 3))))
    b = Mesh(ico_sphere(0).verts, ico_sphere(0).faces, TexturesVertex(np.ones((12, 2))))
    with pytest.raises(ValueError, match="channel counts"):
        sample_points_from_meshes(Meshes([a, b]), 5, return_textures=True)


@pytest.mark.parametrize("n", [0, -3, 2.5, True, "10", None])
def test_bad_num_samples(n):
    with pytest.raises(ValueError, match="num_samples"):
        sample_points_from_meshes(ico_sphere(0), n)
    with pytest.raises(ValueError, match="num_samples"):
        sample_points_with_jacobian(ico_sphere(0), n)


def test_validation_errors():
    """Every invalid input raises with the argument named."""
    with pytest.raises(TypeError, match="mesh"):
        sample_points_from_meshes(np.zeros((3, 3)), 10)
    with pytest.raises(TypeError, match="seed"):
        sample_points_from_meshes(ico_sphere(0), 10, seed="abc")
    # NaN / inf vertices are rejected when the Mesh is built or updated (PyTorch3D raises too)
    bad = ico_sphere(0).verts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="verts"):
        Mesh(bad, ico_sphere(0).faces)
    bad[3, 1] = np.inf
    with pytest.raises(ValueError, match="verts"):
        ico_sphere(0).update_verts(bad)
    # coordinates so large that the area overflows to inf
    with pytest.raises(ValueError, match="not finite"):
        sample_points_from_meshes(ico_sphere(0).scale_verts(1e200), 10)
    # zero total area: all vertices collinear
    flat = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), [[0, 1, 2]])
    with pytest.raises(ValueError, match="area is zero"):
        sample_points_from_meshes(flat, 10)
    with pytest.raises(ValueError, match="no faces"):
        sample_points_from_meshes(Mesh(np.zeros((3, 3)), np.zeros((0, 3), np.int64)), 10)
    with pytest.raises(ValueError, match="no textures"):
        sample_points_from_meshes(ico_sphere(0), 10, return_textures=True)
    with pytest.raises(ValueError, match=r"mesh\[1\]"):
        sample_points_from_meshes(Meshes([ico_sphere(0), flat]), 10)


def test_docstring_examples_run():
    """The Examples sections of geofit.ops.sampling run as doctests."""
    import doctest

    import geofit.ops.sampling as mod

    result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0
