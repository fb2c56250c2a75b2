"""geofit.metrics: chamfer-L2/L1, F-score, normal consistency from exact point-to-surface distances."""
from __future__ import annotations

import numpy as np
import pytest

from geofit import Mesh, ico_sphere, plane
from geofit.metrics import (
    MeshEvaluator,
    chamfer_l1,
    chamfer_l2,
    evaluate_mesh,
    fscore,
    normal_consistency,
)
from geofit.raycast import PointToMeshDistance


def rotate_x(mesh, theta):
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return mesh.update_verts(mesh.verts @ R.T)


def test_identical_meshes_are_perfect():
    """A mesh against itself: chamfer 0, F-score 1, normal consistency 1."""
    m = ico_sphere(2)
    r = evaluate_mesh(m, m, n_samples=5000, taus=(0.001, 0.01))
    assert r.chamfer_l2 < 1e-24 and r.chamfer_l1 < 1e-11 and r.hausdorff < 1e-11
    assert r.fscore == {0.001: 1.0, 0.01: 1.0}
    assert r.normal_consistency == pytest.approx(1.0, abs=1e-12)


def test_parallel_planes_closed_form():
    """Two equal squares h apart: every distance is exactly h."""
    h = 0.03
    a, b = plane(2.0, 4), plane(2.0, 3, z=h)
    r = evaluate_mesh(a, b, n_samples=3000, taus=(h * 0.999, h * 1.001))
    np.testing.assert_allclose(r.chamfer_l2, 2 * h * h, rtol=1e-12)
    np.testing.assert_allclose(r.chamfer_l1, 2 * h, rtol=1e-12)
    assert r.fscore[h * 0.999] == 0.0 and r.fscore[h * 1.001] == 1.0
    assert r.normal_consistency == pytest.approx(1.0, abs=1e-12)


def test_concentric_spheres():
    """Radius 1 and 1.1: chamfer-L2 ~ 2 * 0.1^2, F@0.05 = 0, F@0.2 = 1."""
    a = ico_sphere(4)
    b = a.update_verts(1.1 * a.verts)
    r = evaluate_mesh(a, b, n_samples=20000, taus=(0.05, 0.2))
    np.testing.assert_allclose(r.chamfer_l2, 0.02, rtol=0.01)
    np.testing.assert_allclose(r.chamfer_l1, 0.2, rtol=0.01)
    assert r.fscore[0.05] == 0.0 and r.fscore[0.2] == 1.0
    assert r.normal_consistency > 0.999


def test_precision_recall_asymmetry():
    """A prediction covering a quarter of the target: precision 1, recall ~ 1/4."""
    target = plane(2.0, 8)
    pred = plane(1.0, 2)
    r = evaluate_mesh(pred, target, n_samples=40000, taus=0.01)
    assert r.precision[0.01] == 1.0
    np.testing.assert_allclose(r.recall[0.01], 0.25 + 0.01 * 4 / 4, atol=0.01)
    p, q = r.precision[0.01], r.recall[0.01]
    np.testing.assert_allclose(r.fscore[0.01], 2 * p * q / (p + q), rtol=1e-15)


def test_normal_consistency_tilted_plane():
    """A plane tilted by theta about the x axis has |cos| = cos(theta) at every sample."""
    theta = 0.3
    a = plane(1.0, 2)
    b = rotate_x(a, theta)
    assert normal_consistency(a, b, n_samples=2000) == pytest.approx(np.cos(theta), abs=1e-12)
    flipped = Mesh(a.verts, a.faces[:, ::-1])  # orientation is ignored
    assert normal_consistency(a, flipped, n_samples=2000) == pytest.approx(1.0, abs=1e-12)


def test_reproducible_and_seeded():
    a = ico_sphere(2)
    b = a.update_verts(a.verts * np.array([1.0, 0.9, 1.1]))
    ev = MeshEvaluator(b, n_samples=3000, seed=7)
    r1, r2 = ev.evaluate(a), ev(a)
    assert r1 == r2
    assert evaluate_mesh(a, b, n_samples=3000, seed=7) == r1
    assert evaluate_mesh(a, b, n_samples=3000, seed=8).chamfer_l2 != r1.chamfer_l2
    assert chamfer_l2(a, b, n_samples=3000, seed=7) == r1.chamfer_l2
    assert chamfer_l1(a, b, n_samples=3000, seed=7) == r1.chamfer_l1
    assert fscore(a, b, 0.01, n_samples=3000, seed=7) == r1.fscore[0.01]


def test_normalize_evaluates_in_target_frame():
    """With normalize=True a similarity transform applied to both meshes changes nothing."""
    a = ico_sphere(2)
    b = a.update_verts(a.verts * np.array([1.0, 0.8, 1.2]) + 0.05)
    ref = evaluate_mesh(a, b, n_samples=3000, normalize=True)
    s, t = 3.0, np.array([5.0, -2.0, 1.0])
    moved = evaluate_mesh(a.update_verts(s * a.verts + t), b.update_verts(s * b.verts + t),
                          n_samples=3000, normalize=True)
    np.testing.assert_allclose(moved.chamfer_l2, ref.chamfer_l2, rtol=1e-9)
    assert moved.fscore == ref.fscore
    raw = evaluate_mesh(a.update_verts(s * a.verts + t), b.update_verts(s * b.verts + t),
                        n_samples=3000)
    norm_scale = np.abs(b.verts - b.verts.mean(0)).max()
    np.testing.assert_allclose(raw.chamfer_l2, ref.chamfer_l2 * (s * norm_scale) ** 2, rtol=1e-9)


def test_collapsed_prediction_gives_finite_metrics():
    """A prediction of zero area (all vertices at one point) is scored as that point."""
    target = ico_sphere(2)
    pred = Mesh(np.zeros((12, 3)), ico_sphere(0).faces)
    r = evaluate_mesh(pred, target, n_samples=2000)
    assert np.isfinite(r.chamfer_l2) and np.isfinite(r.normal_consistency)
    # pred -> target: the inradius r of the polyhedron; target -> pred: |sample| in [r, 1]
    r_in = PointToMeshDistance(target).distance(np.zeros((1, 3)))[0]
    assert 2 * r_in ** 2 <= r.chamfer_l2 <= r_in ** 2 + 1.0
    assert r.fscore[0.01] == 0.0


def test_as_dict_keys():
    m = ico_sphere(1)
    d = evaluate_mesh(m, m, n_samples=100, taus=(0.01, 0.05)).as_dict("final_")
    assert {"final_chamfer_l2", "final_fscore@0.01", "final_fscore@0.05",
            "final_normal_consistency"} <= set(d)
    assert set(evaluate_mesh(m, m, n_samples=100).to_dict()["fscore"]) == {"0.01"}


def test_validation():
    m = ico_sphere(1)
    with pytest.raises(TypeError, match="target"):
        MeshEvaluator(m.verts)
    with pytest.raises(TypeError, match="pred"):
        MeshEvaluator(m).evaluate("not a mesh")
    # a (verts, faces) pair is a mesh wherever a mesh is taken (issue 26)
    assert MeshEvaluator(m, n_samples=100).evaluate((m.verts, m.faces)).chamfer_l2 < 1e-20
    with pytest.raises(ValueError, match="n_samples"):
        evaluate_mesh(m, m, n_samples=0)
    with pytest.raises(ValueError, match="taus"):
        evaluate_mesh(m, m, taus=(0.01, -1.0))
    with pytest.raises(ValueError, match="taus"):
        evaluate_mesh(m, m, taus=())
    with pytest.raises(ValueError, match="tau"):
        fscore(m, m, tau=0.0)
    with pytest.raises(ValueError, match="at least one face"):
        evaluate_mesh(m, Mesh(m.verts, np.zeros((0, 3), np.int64)))


def test_image_metric_and_huber_docstring_examples():
    """The Examples of geofit.metrics (psnr, silhouette_iou) and geofit.loss.robust (huber) run."""
    import doctest

    import geofit.loss.robust as gh
    import geofit.metrics as gm

    for mod in (gm, gh):
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0, mod.__name__
        assert result.attempted > 0, mod.__name__


def test_psnr_per_image_matches_one_call_per_image():
    """per_image=True equals psnr of each image on its own; identical images give inf, not NaN."""
    from numpy.testing import assert_allclose

    from geofit.metrics import psnr

    rng = np.random.default_rng(3)
    a = rng.random((3, 5, 4, 3))
    b = a + rng.normal(scale=[[[[0.01]]], [[[0.1]]], [[[0.0]]]], size=a.shape)
    got = psnr(a, b, per_image=True)
    assert got.shape == (3,) and got[2] == np.inf
    for i in range(2):
        assert_allclose(got[i], psnr(a[i], b[i]), rtol=1e-14)
    assert_allclose(psnr(a[:1], b[:1], max_value=2.0, per_image=True),
                    psnr(a[0], b[0]) + 20 * np.log10(2.0), rtol=1e-14)
    with pytest.raises(ValueError, match="pred"):
        psnr(1.0, 1.0, per_image=True)
    with pytest.raises(ValueError, match="shapes"):
        psnr(a, b[:2], per_image=True)
