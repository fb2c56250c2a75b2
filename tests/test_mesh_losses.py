"""Mesh regularisers and Laplacian matrices: PyTorch3D parity, finite differences, closed forms."""
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geofit import Mesh, Meshes, box, ico_sphere, plane
from geofit.loss import (
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
    mesh_normal_variation,
    normal_consistency_pairs,
)
from geofit.ops import cot_laplacian, norm_laplacian, uniform_laplacian

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def ref():
    with np.load(DATA / "mesh_ops.npz") as d:  # stored compactly: widen back
        return {k: d[k].astype(np.int64 if d[k].dtype.kind == "i" else np.float64) for k in d.files}


def _noisy(mesh, sigma=0.05, seed=0):
    rng = np.random.default_rng(seed)
    return mesh.update_verts(mesh.verts + rng.normal(0, sigma, mesh.verts.shape))


def _fd_grad(f, V, h=1e-6):
    """Central finite differences of a scalar function of (V, 3) vertices, every coordinate."""
    g = np.zeros_like(V)
    for idx in np.ndindex(*V.shape):  # loop over the coordinates of a tiny test mesh
        Vp = V.copy()
        Vm = V.copy()
        Vp[idx] += h
        Vm[idx] -= h
        g[idx] = (f(Vp) - f(Vm)) / (2 * h)
    return g


def _f32_weight(count):
    """PyTorch3D's float32 1/count weight relative to the exact 1/count."""
    return float(np.float32(1.0) / np.float32(count)) * count


def _rotation(seed=3):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _nonmanifold():
    """Three fins sharing the edge (0, 1) plus a fourth through the same edge, and a flap."""
    verts = np.array([
        [0.0, 0, 0], [1.0, 0.1, 0], [0.5, 1.0, 0.2], [0.4, -0.8, 0.7], [0.6, -0.3, -1.0],
        [0.3, 0.6, -0.8], [1.2, 1.1, 0.5],
    ])
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [5, 1, 0], [1, 6, 2]])
    return Mesh(verts, faces)


# --------------------------------------------------------------------------- parity
@pytest.mark.parametrize("prefix", ["test", "obj"])
def test_edge_and_normal_consistency_match_pytorch3d(ref, prefix):
    """Values and gradients equal PyTorch3D's float64 results once its float32 1/count is applied."""
    m = Mesh(ref[f"{prefix}_verts"], ref[f"{prefix}_faces"])
    f_edge = _f32_weight(len(m.edges))
    for key, t in (("edge_t0", 0.0), ("edge_t01", 0.1)):
        v, g = mesh_edge_loss(m, target_length=t)
        assert_allclose(v * f_edge, ref[f"{prefix}_{key}"], rtol=1e-12)
        assert_allclose(g * f_edge, ref[f"{prefix}_{key}_grad"], rtol=1e-9,
                        atol=1e-12 * np.abs(g).max())
        assert_allclose(v, ref[f"{prefix}_{key}"], rtol=1e-7)  # the brief's tolerance, no factor
    P = len(normal_consistency_pairs(m)["v0"])
    if prefix == "obj":  # the cow has more pairs than one kernel block: covers the block loop
        from geofit.loss.mesh import _NC_CHUNK

        assert P > _NC_CHUNK
    f_nc = _f32_weight(P)
    v, g = mesh_normal_consistency(m)
    assert_allclose(v * f_nc, ref[f"{prefix}_normal_consistency"], rtol=1e-12)
    assert_allclose(g * f_nc, ref[f"{prefix}_normal_consistency_grad"], rtol=1e-9,
                    atol=1e-12 * np.abs(g).max())


@pytest.mark.parametrize("method", ["uniform", "cot", "cotcurv"])
def test_laplacian_smoothing_matches_pytorch3d_test_mesh(ref, method):
    """ico_sphere(2) + noise: value to 1e-6 and gradient to 5e-5 of its largest entry (float32 ref)."""
    m = Mesh(ref["test_verts"], ref["test_faces"])
    v, g = mesh_laplacian_smoothing(m, method)
    r = ref[f"test_laplacian_{method}_grad"]
    assert_allclose(v, ref[f"test_laplacian_{method}"], rtol=1e-6)
    assert np.abs(g - r).max() / np.abs(r).max() < 5e-5


@pytest.mark.parametrize("method", ["uniform", "cot", "cotcurv"])
def test_laplacian_smoothing_matches_pytorch3d_cow(ref, method):
    """The cow: value to 2e-6; gradients agree to float32 accuracy.

    PyTorch3D ran this in float32, and the residual r_i = (L V)_i (/ rowsum) - v_i is a difference
    of nearly equal vectors (|r| ~ 1e-5 against |v| ~ 1), so r_i / |r_i| carries relative errors up
    to ~1e-2 at the vertices with the smallest residuals. Most rows agree to 1e-5 of the largest
    entry; the worst rows are the ones with the smallest |r_i| (checked below).
    """
    m = Mesh(ref["obj_verts"], ref["obj_faces"])
    v, g = mesh_laplacian_smoothing(m, method)
    r = ref[f"obj_laplacian_{method}_grad"]
    assert_allclose(v, ref[f"obj_laplacian_{method}"], rtol=2e-6)
    err = np.abs(g - r).max(axis=1) / np.abs(r).max()
    assert np.median(err) < 1e-5
    assert np.quantile(err, 0.9) < 1e-4
    assert err.max() < 1e-2


def test_cow_cot_gradient_errors_sit_at_small_residuals(ref):
    """The largest float32 disagreements (cot) are at vertices whose own residual is tiny."""
    m = Mesh(ref["obj_verts"], ref["obj_faces"])
    g = mesh_laplacian_smoothing(m, "cot")[1]
    r = ref["obj_laplacian_cot_grad"]
    L, _ = cot_laplacian(m.verts, m.faces)
    w = 1.0 / np.asarray(L.sum(axis=1)).ravel()
    res = np.linalg.norm((L @ m.verts) * w[:, None] - m.verts, axis=1)
    worst = np.argsort(np.abs(g - r).max(axis=1))[-5:]
    # each worst row has (or neighbours) a residual in the smallest 2% of the mesh
    small = res < np.quantile(res, 0.02)
    A = uniform_laplacian(m) != 0
    near_small = small | (A @ small.astype(float) > 0)
    assert np.all(near_small[worst])


# --------------------------------------------------------------------------- finite differences
@pytest.mark.parametrize("t", [0.0, 0.3])
def test_edge_loss_finite_differences(t):
    m = _noisy(ico_sphere(1), seed=1)
    _v, g = mesh_edge_loss(m, t)
    fd = _fd_grad(lambda V: mesh_edge_loss(m.update_verts(V), t)[0], m.verts)
    assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("mesh", [_noisy(ico_sphere(1), seed=2), _nonmanifold(),
                                  _noisy(plane(n=3), sigma=0.1, seed=4)],
                         ids=["sphere", "nonmanifold", "open_plane"])
def test_normal_consistency_finite_differences(mesh):
    _v, g = mesh_normal_consistency(mesh)
    fd = _fd_grad(lambda V: mesh_normal_consistency(mesh.update_verts(V))[0], mesh.verts)
    assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def _frozen_laplacian_value(mesh, method):
    """The smoothing value as a function of V with L (and its weights) frozen at mesh.verts."""
    V0, F = mesh.verts, mesh.faces
    n = len(V0)
    if method == "uniform":
        L = uniform_laplacian(mesh)
        return lambda V: np.linalg.norm(L @ V, axis=1).sum() / n
    L, inv_a = cot_laplacian(V0, F)
    rs = np.asarray(L.sum(axis=1)).ravel()
    if method == "cot":
        w = np.where(rs > 0, 1.0 / np.where(rs > 0, rs, 1.0), rs)
        return lambda V: np.linalg.norm((L @ V) * w[:, None] - V, axis=1).sum() / n
    s = 0.25 * inv_a
    return lambda V: np.linalg.norm(((L @ V) - rs[:, None] * V) * s[:, None], axis=1).sum() / n


@pytest.mark.parametrize("method", ["uniform", "cot", "cotcurv"])
def test_laplacian_smoothing_finite_differences(method):
    """The gradient is exact for the loss with L held constant (PyTorch3D's no_grad L)."""
    m = _noisy(ico_sphere(1), sigma=0.08, seed=5)
    v, g = mesh_laplacian_smoothing(m, method)
    f = _frozen_laplacian_value(m, method)
    assert_allclose(f(m.verts), v, rtol=1e-13)
    fd = _fd_grad(f, m.verts)
    assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_laplacian_zero_residual_gives_zero_gradient_not_nan():
    """Where r_i = 0 the kink takes the zero subgradient: no NaN, no contribution from that row."""
    m = plane(n=4)
    # a flat regular grid: every interior residual is exactly 0 (uniform and cot)
    L = uniform_laplacian(m)
    interior = np.flatnonzero(m.topology.degrees == 6)
    assert len(interior) == 9
    r = L @ m.verts
    assert_allclose(r[interior], 0.0, atol=1e-15)
    Lc, _ = cot_laplacian(m.verts, m.faces)
    rs = np.asarray(Lc.sum(axis=1)).ravel()
    assert_allclose(((Lc @ m.verts) / rs[:, None] - m.verts)[interior], 0.0, atol=1e-14)
    # a fan whose centre sits exactly at its neighbours' centroid (r_0 == 0 in floating point:
    # weights 1/4, symmetric ring): the gradient is L^T u / V with u_0 = 0, u_i = r_i / |r_i|
    ring = np.array([[1.0, 0, 0], [0, 1, 0.5], [-1, 0, 0], [0, -1, -0.5]])
    fan = Mesh(np.vstack([[0.0, 0, 0], ring]), [[0, i, i % 4 + 1] for i in range(1, 5)])
    Lf = uniform_laplacian(fan)
    rf = Lf @ fan.verts
    assert not rf[0].any()
    u = np.zeros_like(rf)
    u[1:] = rf[1:] / np.linalg.norm(rf[1:], axis=1, keepdims=True)
    _v, g = mesh_laplacian_smoothing(fan, "uniform")
    assert_allclose(g, Lf.T @ u / 5, rtol=1e-14, atol=1e-17)
    assert np.abs(g).max() > 0.01
    for method in ("cot", "cotcurv"):
        assert np.all(np.isfinite(mesh_laplacian_smoothing(m, method)[1]))
    # every vertex at one point: all residuals 0, value 0 and gradient exactly 0 (uniform)
    collapsed = m.update_verts(np.zeros_like(m.verts))
    v, g = mesh_laplacian_smoothing(collapsed, "uniform")
    assert v == 0.0 and not g.any()


def test_edge_loss_zero_length_edge_kink():
    """A collapsed edge with t != 0 contributes the zero subgradient (finite gradient)."""
    m = Mesh(np.array([[0.0, 0, 0], [0.0, 0, 0], [0, 1, 0]]), [[0, 1, 2]])
    v, g = mesh_edge_loss(m, 0.5)
    assert np.all(np.isfinite(g))
    assert_allclose(v, (0.25 + 0.25 + (np.sqrt(1.0) - 0.5) ** 2) / 3)


# --------------------------------------------------------------------------- slow references
def _slow_normal_consistency(V, F):
    """Loop reference: for every edge, every pair of faces on it, PyTorch3D's formula."""
    by_edge = {}
    for f in F.tolist():
        for k in range(3):
            a, b = f[(k + 1) % 3], f[(k + 2) % 3]
            by_edge.setdefault((min(a, b), max(a, b)), []).append(f[k])
    terms = []
    pairs = []
    for (v0, v1), opp in sorted(by_edge.items()):
        for j in range(len(opp)):
            for i in range(j):
                a, b = opp[i], opp[j]
                n0 = np.cross(V[v1] - V[v0], V[a] - V[v0])
                n1 = np.cross(V[b] - V[v0], V[v1] - V[v0])
                c = n0 @ n1 / (max(np.linalg.norm(n0), 1e-8) * max(np.linalg.norm(n1), 1e-8))
                terms.append(1 - c)
                pairs.append((v0, v1, min(a, b), max(a, b)))
    return (np.mean(terms) if terms else 0.0), sorted(pairs)


@pytest.mark.parametrize("mesh", [_noisy(ico_sphere(1), seed=6), _nonmanifold(), box(),
                                  _noisy(plane(n=2), 0.1, seed=7)],
                         ids=["sphere", "nonmanifold", "box", "plane"])
def test_normal_consistency_vectorised_pairs_match_loop(mesh):
    """The vectorised pairs and value equal a Python loop over edges and face pairs."""
    v_ref, pairs_ref = _slow_normal_consistency(mesh.verts, mesh.faces)
    p = normal_consistency_pairs(mesh)
    pairs = sorted(zip(p["v0"].tolist(), p["v1"].tolist(),
                       np.minimum(p["a"], p["b"]).tolist(), np.maximum(p["a"], p["b"]).tolist()))
    assert pairs == pairs_ref
    assert_allclose(mesh_normal_consistency(mesh)[0], v_ref, rtol=1e-13)
    # the faces recorded for each pair contain the edge and their opposite vertex
    F = mesh.faces
    for key, opp in (("face_i", "a"), ("face_j", "b")):
        rows = F[p[key]]
        for col in ("v0", "v1", opp):
            assert np.all(np.any(rows == p[col][:, None], axis=1))


def test_nonmanifold_pair_counts():
    """An edge with c faces yields c (c - 1) / 2 pairs; boundary edges none."""
    m = _nonmanifold()
    p = normal_consistency_pairs(m)
    e = m.edges.tolist().index([0, 1])
    assert np.sum(p["edge"] == e) == 6  # 4 faces on edge (0, 1)
    assert len(p["v0"]) == 6 + 1  # plus edge (1, 2) shared by faces 0 and 4


# --------------------------------------------------------------------------- closed forms
def test_edge_loss_equilateral_triangle():
    """Side s, target t: value (s - t)^2; gradient at t = 0 is (2/3)(2 v_i - v_j - v_k)."""
    s = 2.0
    V = np.array([[0.0, 0, 0], [s, 0, 0], [s / 2, s * np.sqrt(3) / 2, 0]])
    m = Mesh(V, [[0, 1, 2]])
    for t in (0.0, 0.5, 2.0):
        assert_allclose(mesh_edge_loss(m, t)[0], (s - t) ** 2, rtol=1e-14, atol=1e-15)
    g = mesh_edge_loss(m)[1]
    expected = np.array([2 / 3 * (2 * V[i] - V[(i + 1) % 3] - V[(i + 2) % 3]) for i in range(3)])
    assert_allclose(g, expected, rtol=1e-14, atol=1e-15)


def test_normal_consistency_closed_forms():
    """Flat plane: 0 with zero gradient; a right-angle hinge: 1; the cube: 12 of 18 pairs are 1."""
    v, g = mesh_normal_consistency(plane(n=3))
    assert v == 0.0
    assert_allclose(g, 0.0, atol=1e-15)
    hinge = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), [[0, 1, 2], [1, 0, 3]])
    assert_allclose(mesh_normal_consistency(hinge)[0], 1.0, rtol=1e-15)
    b = box()
    assert len(normal_consistency_pairs(b)["v0"]) == 18
    assert_allclose(mesh_normal_consistency(b)[0], 12 / 18, rtol=1e-14)


def test_normal_consistency_ignores_winding():
    """Flipping the orientation of some faces leaves the value unchanged (edge-based normals)."""
    m = _noisy(ico_sphere(1), seed=8)
    F = m.faces.copy()
    F[::3] = F[::3, ::-1]
    assert_allclose(mesh_normal_consistency(Mesh(m.verts, F))[0], mesh_normal_consistency(m)[0],
                    rtol=1e-13)


# --------------------------------------------------------------------------- invariants
def test_rigid_motion_invariance():
    """Edge, normal and Laplacian losses are invariant to rotation + translation; gradients rotate."""
    m = _noisy(ico_sphere(2), seed=9)
    R = _rotation()
    moved = m.update_verts(m.verts @ R + [0.3, -1.0, 2.0])
    for fn in (lambda x: mesh_edge_loss(x, 0.2), mesh_normal_consistency,
               lambda x: mesh_laplacian_smoothing(x, "uniform"),
               lambda x: mesh_laplacian_smoothing(x, "cot"),
               lambda x: mesh_laplacian_smoothing(x, "cotcurv")):
        v0, g0 = fn(m)
        v1, g1 = fn(moved)
        assert_allclose(v1, v0, rtol=1e-11)
        assert_allclose(g1, g0 @ R, rtol=1e-8, atol=1e-11 * np.abs(g0).max())


def test_laplacian_matrix_invariants():
    """Uniform rows sum to 0 with -1 diagonal; cot L is symmetric with zero diagonal."""
    m = _noisy(ico_sphere(2), seed=10)
    L = uniform_laplacian(m)
    assert_allclose(np.asarray(L.sum(axis=1)).ravel(), 0.0, atol=1e-15)
    assert_allclose(L.diagonal(), -1.0)
    assert_array_equal(np.diff(L.indptr), m.topology.degrees + 1)
    Lc, inv_a = cot_laplacian(m.verts, m.faces)
    assert abs(Lc - Lc.T).max() == 0.0
    assert_allclose(Lc.diagonal(), 0.0)
    areas = np.bincount(m.faces.ravel(), np.repeat(m.face_areas, 3), m.n_verts)
    assert_allclose(inv_a, 1.0 / areas, rtol=1e-10)


def test_cot_laplacian_matches_loop_over_faces():
    """Each face adds cot(angle at a corner) to the opposite edge, both directions."""
    m = _noisy(ico_sphere(1), seed=11)
    V, F = m.verts, m.faces
    dense = np.zeros((m.n_verts, m.n_verts))
    for f in F:  # loop over 80 faces of a tiny test mesh
        for k in range(3):
            i, j, o = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
            a, b = V[i] - V[o], V[j] - V[o]
            c = a @ b / np.linalg.norm(np.cross(a, b))
            dense[i, j] += c
            dense[j, i] += c
    L, _ = cot_laplacian(V, F)
    assert_allclose(L.toarray(), dense, rtol=1e-10, atol=1e-12)


def test_uniform_laplacian_is_cached_per_topology_and_read_only():
    m = ico_sphere(2)
    m2 = m.update_verts(m.verts * 2)
    assert uniform_laplacian(m) is uniform_laplacian(m2)
    with pytest.raises(ValueError):
        uniform_laplacian(m).data[0] = 5.0
    assert normal_consistency_pairs(m)["v0"] is normal_consistency_pairs(m2)["v0"]


def test_norm_laplacian():
    """L_ij = 1 / (|v_i - v_j| + eps), symmetric, on the edges only."""
    m = _noisy(ico_sphere(0), seed=12)
    L = norm_laplacian(m.verts, m.edges)
    e = m.edges
    lens = np.linalg.norm(m.verts[e[:, 0]] - m.verts[e[:, 1]], axis=1)
    assert_allclose(np.asarray(L[e[:, 0], e[:, 1]]).ravel(), 1 / (lens + 1e-12))
    assert abs(L - L.T).max() == 0.0 and L.nnz == 2 * len(e)


def test_uniform_laplacian_batch_is_block_diagonal():
    a, b = ico_sphere(0), box()
    L = uniform_laplacian(Meshes([a, b]))
    assert L.shape == (20, 20)
    assert_allclose(L[:12, :12].toarray(), uniform_laplacian(a).toarray())
    assert L[:12, 12:].nnz == 0


def test_batch_losses_average_meshes():
    """A Meshes batch gives the mean of the per-mesh values and the packed gradient / N."""
    a, b = _noisy(ico_sphere(1), seed=13), _noisy(box(), 0.05, seed=14)
    batch = Meshes([a, b])
    for fn in (mesh_edge_loss, mesh_normal_consistency,
               lambda x: mesh_laplacian_smoothing(x, "cot")):
        va, ga = fn(a)
        vb, gb = fn(b)
        v, g = fn(batch)
        assert_allclose(v, (va + vb) / 2, rtol=1e-14)
        assert_allclose(g, np.concatenate([ga, gb]) / 2, rtol=1e-14)


def test_empty_meshes_give_zero():
    empty = Mesh(np.zeros((4, 3)), np.zeros((0, 3), np.int64))
    for fn in (mesh_edge_loss, mesh_normal_consistency, mesh_laplacian_smoothing):
        v, g = fn(empty)
        assert v == 0.0 and g.shape == (4, 3) and not g.any()
    v, g = mesh_normal_consistency(Mesh(np.eye(3), [[0, 1, 2]]))  # no shared edge: no pairs
    assert v == 0.0 and not g.any()
    assert mesh_edge_loss(Meshes([]))[0] == 0.0


# --------------------------------------------------------------------------- validation
def test_validation_errors():
    m = ico_sphere(0)
    with pytest.raises(ValueError, match="method"):
        mesh_laplacian_smoothing(m, "cotangent")
    for bad in (np.nan, np.inf, "a", None):
        with pytest.raises(ValueError, match="target_length"):
            mesh_edge_loss(m, bad)
    for fn in (mesh_edge_loss, mesh_normal_consistency, mesh_laplacian_smoothing,
               uniform_laplacian):
        with pytest.raises(TypeError, match="mesh"):
            fn(m.verts)
    with pytest.raises(TypeError, match="mesh"):
        normal_consistency_pairs(Meshes([m]))
    with pytest.raises(ValueError, match="eps"):
        cot_laplacian(m.verts, m.faces, eps=0.0)
    with pytest.raises(ValueError, match="faces"):
        cot_laplacian(m.verts, m.faces + 12)
    with pytest.raises(ValueError, match="verts"):
        cot_laplacian(m.verts[:, :2], m.faces)
    with pytest.raises(ValueError, match="edges"):
        norm_laplacian(m.verts, m.edges + 12)
    with pytest.raises(ValueError, match="edges"):
        norm_laplacian(m.verts, m.faces)
    with pytest.raises(ValueError, match="eps"):
        norm_laplacian(m.verts, m.edges, eps=-1.0)
    with pytest.raises(ValueError, match="verts"):
        norm_laplacian(np.full((12, 3), np.nan), m.edges)


# --------------------------------------------------------------------------- normal variation
@pytest.mark.parametrize("mesh", [_noisy(ico_sphere(1), seed=2), _nonmanifold(),
                                  _noisy(plane(n=3), sigma=0.1, seed=4)],
                         ids=["sphere", "nonmanifold", "open_plane"])
@pytest.mark.parametrize("eps", [0.05, 1.0])
def test_normal_variation_finite_differences(mesh, eps):
    _v, g = mesh_normal_variation(mesh, eps)
    fd = _fd_grad(lambda V: mesh_normal_variation(mesh.update_verts(V), eps)[0], mesh.verts)
    assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_normal_variation_closed_forms_and_loop():
    """Flat plane: 0 with zero gradient; a right-angle hinge: sqrt(2 + eps^2) - eps; the value
    equals a loop over the normal-consistency pairs; rigid motions leave it unchanged."""
    v, g = mesh_normal_variation(plane(n=3), 0.1)
    assert v == 0.0
    assert_allclose(g, 0.0, atol=1e-15)
    hinge = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), [[0, 1, 2], [1, 0, 3]])
    assert_allclose(mesh_normal_variation(hinge, 0.1)[0], np.sqrt(2.01) - 0.1, rtol=1e-14)
    m = _noisy(ico_sphere(1), seed=5)
    p = normal_consistency_pairs(m)
    V = m.verts
    total = 0.0
    for v0, v1, a, b in zip(p["v0"], p["v1"], p["a"], p["b"]):  # reference loop over pairs
        n0 = np.cross(V[v1] - V[v0], V[a] - V[v0])
        n1 = np.cross(V[b] - V[v0], V[v1] - V[v0])
        d = n0 / np.linalg.norm(n0) - n1 / np.linalg.norm(n1)
        total += np.sqrt(d @ d + 0.04) - 0.2
    assert_allclose(mesh_normal_variation(m, 0.2)[0], total / len(p["v0"]), rtol=1e-12)
    R = _rotation()
    assert_allclose(mesh_normal_variation(m.update_verts(V @ R.T + 0.3), 0.2)[0],
                    total / len(p["v0"]), rtol=1e-12)


def _hinge(bend):
    """Two triangles on the z axis whose normals differ by ``bend`` radians."""
    return Mesh(np.array([[0.0, 0, 0], [0, 0, 1], [1, 0, 0],
                          [-np.cos(bend), -np.sin(bend), 0]]), [[0, 1, 2], [1, 0, 3]])


def test_normal_variation_does_not_pay_to_round_a_crease():
    """Linear above eps: a right-angle crease spread over two 45-degree bends costs about as
    much as the crease (normal consistency halves it, so it rounds creases)."""
    eps = 0.01
    sharp = mesh_normal_variation(_hinge(np.pi / 2), eps)[0]
    spread = 2 * mesh_normal_variation(_hinge(np.pi / 4), eps)[0]
    assert_allclose(sharp, np.sqrt(2 + eps ** 2) - eps, rtol=1e-12)
    assert spread > 1.05 * sharp
    assert 2 * mesh_normal_consistency(_hinge(np.pi / 4))[0] < 0.6 * \
        mesh_normal_consistency(_hinge(np.pi / 2))[0]


def test_normal_variation_validates_eps():
    for bad in (0.0, -1.0, np.inf, "a"):
        with pytest.raises(ValueError, match="eps"):
            mesh_normal_variation(plane(n=3), bad)
