"""fit_mesh on point-cloud targets: the cloud objective's gradient, normals, first mesh, fits."""
from __future__ import annotations

import numpy as np
import pytest

from geofit import ico_sphere
from geofit.fit import MeshFitOptions, MeshObjective, Remeshing, fit_mesh
from geofit.fit._cloud import (
    CloudTarget,
    as_cloud_points,
    close_small_loops,
    mesh_from_points,
    orient_normals,
)
from geofit.metrics import evaluate_mesh
from geofit.ops import sample_points_from_meshes, topology
from geofit.shapes import open_cylinder, torus

ALL_TERMS = {"chamfer": 1.3, "edge": 0.7, "normal": 0.2, "laplacian": 0.4}


def cloud_and_source(n=1500):
    """Points on a bumpy ellipsoid, and a perturbed coarse sphere inside it."""
    m = ico_sphere(3)
    d = m.verts
    r = 1.0 + 0.25 * np.exp(-np.sum((d - [0, 0, 1]) ** 2, 1) / 0.1)
    tgt = m.update_verts(d * r[:, None] * [1.0, 0.7, 1.2]).normalize().mesh
    P = sample_points_from_meshes(tgt, n, seed=2)
    src = ico_sphere(1)
    rng = np.random.default_rng(3)
    return P, src.update_verts(src.verts * 0.8 + rng.normal(scale=0.05, size=src.verts.shape))


def test_cloud_objective_gradient_matches_finite_differences():
    """distance="cloud", all four terms: analytic gradient = central differences (float64)."""
    P, src = cloud_and_source()
    obj = MeshObjective(src, P, ALL_TERMS, distance="cloud", n_samples=400, seed=1)
    x = obj.params_from_verts(src.verts)
    value, grad = obj(x)
    np.testing.assert_allclose(value, sum(ALL_TERMS[k] * v for k, v in obj.last_terms.items()),
                               rtol=1e-12)
    idx = np.random.default_rng(0).choice(x.size, 25, replace=False)
    h = 1e-6
    fd = []
    for i in idx:  # a handful of coordinates
        e = np.zeros_like(x)
        e[i] = h
        fd.append((obj(x + e)[0] - obj(x - e)[0]) / (2 * h))
    np.testing.assert_allclose(grad[idx], fd, rtol=2e-4, atol=1e-7 * np.abs(grad).max())


def test_cloud_data_term_matches_reference_loop():
    """The point-to-plane term and its scatter equal a per-sample loop."""
    P, src = cloud_and_source(300)
    obj = MeshObjective(src, P, {"chamfer": 1.0}, distance="cloud", n_samples=50, seed=4)
    _, grad = obj(obj.params_from_verts(src.verts))
    B = obj._B.toarray()
    X = B @ src.verts
    cloud = obj._cloud
    ref_value, ref_grad = 0.0, np.zeros_like(src.verts)
    for i in range(len(X)):  # source samples: nearest cloud point by brute force
        j = int(np.argmin(np.sum((cloud.points - X[i]) ** 2, 1)))
        d, n = X[i] - cloud.points[j], cloud.normals[j]
        r = float(d @ n)
        t = d - r * n
        e = max(float(np.linalg.norm(t)) - cloud.rho, 0.0)
        ref_value += (r * r + e * e) / len(X)
        g = 2 * r * n + (2 * e * t / np.linalg.norm(t) if e > 0 else 0.0)
        ref_grad += np.outer(B[i], g / len(X))
    value, g = cloud.loss(X)
    np.testing.assert_allclose(value, ref_value, rtol=1e-12)
    np.testing.assert_allclose(B.T @ g, ref_grad, atol=1e-14)
    assert grad.shape == (3 * src.n_verts,)


def test_point_to_plane_is_zero_on_a_plane():
    """Closed form: points on a plane have that plane's normal; points moved off it by dz are
    exactly |dz| away (whatever the spacing of the cloud)."""
    g = np.linspace(-1, 1, 15)
    P = np.stack(np.meshgrid(g, g, [0.0], indexing="ij"), -1).reshape(-1, 3)
    c = CloudTarget(P)
    np.testing.assert_allclose(np.abs(c.normals[:, 2]), 1.0, atol=1e-12)
    X = np.array([[0.03, -0.51, 0.2], [0.5, 0.5, -0.07]])
    np.testing.assert_allclose(c.distances(X), [0.2, 0.07], atol=1e-12)
    # past the cloud's edge, in its plane: the distance to the edge point's disk
    X = np.array([[1.0 + c.rho + 0.3, 0.0, 0.0], [1.0 + c.rho + 0.3, 0.0, 0.4]])
    np.testing.assert_allclose(c.distances(X), [0.3, 0.5], atol=1e-12)


def test_cloud_loss_gradient_matches_finite_differences_past_the_edge():
    """The disk distance's gradient (normal and tangential parts) = central differences."""
    g = np.linspace(-1, 1, 9)
    P = np.stack(np.meshgrid(g, g, [0.0], indexing="ij"), -1).reshape(-1, 3)
    c = CloudTarget(P + np.random.default_rng(1).normal(scale=1e-3, size=P.shape))
    X = np.array([[1.61, 0.37, 0.12], [-0.1, 1.9, -0.05], [0.31, 0.12, 0.07]])
    _, grad = c.loss(X)
    h, fd = 1e-7, np.zeros_like(X)
    for i in range(X.size):  # every coordinate (9)
        e = np.zeros(X.size)
        e[i] = h
        e = e.reshape(X.shape)
        fd.flat[i] = (c.loss(X + e)[0] - c.loss(X - e)[0]) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-10)


def test_orient_normals_point_outwards_on_closed_shapes():
    """Consistent orientation: every normal of a torus and a sphere sample points outwards."""
    for m in (torus(1.0, 0.35, 48, 24), ico_sphere(3)):
        P = sample_points_from_meshes(m, 3000, seed=0)
        c = CloudTarget(P)
        N = orient_normals(P, c.normals * np.where(np.arange(len(P)) % 2, 1.0, -1.0)[:, None])
        if m.n_verts == 48 * 24:  # torus (around y): outwards = away from the tube's circle
            ring = P * [1, 0, 1]
            ring /= np.linalg.norm(ring, axis=1, keepdims=True)
            out = P - ring
        else:
            out = P
        assert np.mean(np.einsum("ij,ij->i", N, out) > 0) > 0.99


def test_mesh_from_points_keeps_genus_and_boundaries():
    """The first mesh of a torus sample has genus 1; of an open cylinder, 2 boundary loops."""
    for m, genus, loops in ((torus(1.0, 0.35, 48, 24), 1, 0), (open_cylinder(), 0, 2)):
        P = sample_points_from_meshes(m.normalize().mesh, 8000, seed=1)
        g = mesh_from_points(CloudTarget(P), n_faces=800)
        t = topology(g)
        assert (t.genus, t.n_boundary_loops, t.n_components) == (genus, loops, 1)
        assert g.n_faces <= 800


def test_close_small_loops_closes_small_holes_only():
    """A closed mesh with one face removed (a 3-edge loop) is closed again, manifold, with its
    genus and the face orientation of its neighbours; an open cylinder's large rims stay."""
    m = ico_sphere(2)
    holed = type(m)(m.verts, m.faces[1:])
    assert topology(holed).n_boundary_loops == 1
    closed = close_small_loops(holed)
    t = topology(closed)
    assert t.is_closed and t.is_manifold and t.genus == 0
    assert closed.n_verts == m.n_verts + 1 and closed.n_faces == m.n_faces + 2
    # consistently oriented: every undirected edge is run once each way
    F = closed.faces
    H = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    assert len(np.unique(H, axis=0)) == len(H)
    assert close_small_loops(m) is m
    cyl = open_cylinder()
    assert close_small_loops(cyl) is cyl


def test_fit_mesh_to_points_default():
    """fit_mesh(P) fits a mesh to a torus sample (genus 1 kept), in the points' frame."""
    m = torus(1.0, 0.35, 48, 24).scale_verts(3.0)
    P = sample_points_from_meshes(m, 6000, seed=0)
    res = fit_mesh(P, time_budget=4.0)
    assert res.init == "points" and res.topology.genus == 1
    assert res.metrics is None  # no surface to score a cloud against by default
    met = evaluate_mesh(res.mesh, m, n_samples=10_000, taus=0.01, normalize=True)
    assert met.fscore[0.01] > 0.95 and met.chamfer_l2 < 1e-4
    assert np.all(np.isfinite(res.mesh.verts))


def test_cloud_types_give_the_same_points():
    """A geofit PointCloud, a one-cloud Pointclouds, Open3D and trimesh clouds are points."""
    from geofit.fit._cloud import is_cloud
    from geofit.structures import PointCloud, Pointclouds

    P = np.random.default_rng(0).normal(size=(40, 3))
    clouds = [PointCloud(P.copy()), Pointclouds([PointCloud(P.copy())])]
    o3d = pytest.importorskip("open3d")
    clouds.append(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P.copy())))
    trimesh = pytest.importorskip("trimesh")
    clouds.append(trimesh.PointCloud(P.copy()))
    for c in clouds:
        assert is_cloud(c)
        np.testing.assert_allclose(as_cloud_points(c), P, rtol=0, atol=1e-12)
    assert not is_cloud(ico_sphere(1)) and not is_cloud((P, np.zeros((1, 3), np.int64)))
    with pytest.raises(ValueError, match="one point cloud"):
        as_cloud_points(Pointclouds([PointCloud(P.copy()), PointCloud(P.copy())]))


def test_fit_mesh_adaptive_points_with_sphere_init():
    """init="sphere" with a point cloud starts from the ico-sphere and still fits the points."""
    P = sample_points_from_meshes(ico_sphere(3).scale_verts(2.0), 3000, seed=0)
    res = fit_mesh(P, options=MeshFitOptions(init="sphere", n_iter=10,
                                             refine=Remeshing(max_rounds=1)), evaluator=None)
    assert res.init == "sphere"
    r = np.linalg.norm(res.mesh.verts, axis=1)
    assert abs(np.median(r) - 2.0) < 0.05


@pytest.mark.parametrize("P, match", [
    (np.zeros((5, 3)), "at least 20 points"),
    (np.full((30, 3), np.nan), "target"),
    (np.zeros((30, 2)), "target"),
    (np.ones((30, 3)), "coincide"),
])
def test_cloud_target_validation(P, match):
    with pytest.raises(ValueError, match=match):
        as_cloud_points(P)
    with pytest.raises(ValueError, match=match):
        fit_mesh(P)


def test_cloud_target_with_other_options_is_refused():
    P = sample_points_from_meshes(ico_sphere(2), 500, seed=0)
    with pytest.raises(ValueError, match="point cloud"):
        fit_mesh(P, recipe="tutorial")
