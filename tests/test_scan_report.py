"""What a scan supports (issue 25): noise, spacing and outliers; the fit sized to them."""
from __future__ import annotations

import numpy as np
import pytest

from geofit.fit import fit_mesh
from geofit.fit._scan_report import DataReport, evidence_limits, scan_report
from geofit.ops import sample_points_from_meshes
from geofit.shapes import torus


def noisy_torus(n, sigma, n_out=0, seed=1):
    """``n`` points of a normalised torus with isotropic Gaussian noise ``sigma``, then
    ``n_out`` strays uniform in the bounding box."""
    m = torus(1.0, 0.35, 96, 48).normalize().mesh
    rng = np.random.default_rng(seed)
    P = sample_points_from_meshes(m, n, seed=seed) + rng.normal(0.0, sigma, (n, 3))
    O = rng.uniform(P.min(0), P.max(0), (n_out, 3))
    return m, np.r_[P, O]


@pytest.mark.parametrize("sigma", [0.003, 0.005, 0.01])
def test_noise_estimate_within_25_percent(sigma):
    """The noise level of a torus scan with known Gaussian noise is found within 25%."""
    _, P = noisy_torus(20_000, sigma)
    rep, keep = scan_report(P)
    assert abs(rep.noise - sigma) < 0.25 * sigma
    assert rep.n_points == 20_000 and keep.shape == (20_000,)


def test_noise_estimate_on_a_plane_is_unbiased():
    """On a flat, noisy square (no curvature bias) the estimate is within 10%."""
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1, 1, (20_000, 2)), rng.normal(0, 0.004, 20_000)]
    rep, _ = scan_report(P)
    assert abs(rep.noise - 0.004) < 0.1 * 0.004


def test_clean_scan_has_no_outliers_and_little_noise():
    """A clean scan: no point is called an outlier, the noise is far under the spacing."""
    _, P = noisy_torus(20_000, 0.0)
    rep, keep = scan_report(P)
    assert rep.n_outliers == 0 and keep.all()
    assert rep.noise < 0.25 * rep.spacing
    # the spacing is the median nearest-neighbour distance
    from scipy.spatial import cKDTree
    d = cKDTree(P).query(P, 2)[0][:, 1]
    np.testing.assert_allclose(rep.spacing, np.median(d), rtol=1e-12)


def test_strays_are_found_and_inliers_kept():
    """1% strays in the bounding box: most are removed (those left lie near the surface),
    no surface point is; the reported fraction counts what was removed."""
    from geofit.loss import PointToSurface
    m, P = noisy_torus(20_000, 0.005, n_out=200)
    rep, keep = scan_report(P)
    assert keep[:20_000].mean() > 0.999
    assert (~keep[20_000:]).sum() >= 0.6 * 200
    left = P[20_000:][keep[20_000:]]
    assert np.all(PointToSurface(m).query(left).distances < 0.1)
    assert rep.n_outliers == int((~keep).sum())
    assert rep.outlier_fraction == pytest.approx(rep.n_outliers / len(P))


def test_evidence_limits_relax_to_the_noise_floor_only_on_noisy_scans():
    """Clean: the user's targets; noisy: chamfer >= 2 sigma^2, F below the noise floor."""
    clean = DataReport(50_000, 0, 0.0, 0.006, 0.0005, 16)
    lim = evidence_limits(clean, 3e-5, 0.97, 0.01)
    assert (lim.chamfer_l2, lim.fscore) == (3e-5, 0.97)
    noisy = DataReport(20_000, 0, 0.0, 0.01, 0.005, 16)
    lim = evidence_limits(noisy, 3e-5, 0.97, 0.01)
    assert lim.chamfer_l2 >= 2 * 0.005 ** 2 and lim.fscore < 0.955
    assert lim.max_faces == 20_000 and lim.eps_floor(20_000) == pytest.approx(0.005)
    assert lim.eps_floor(5_000) == pytest.approx(0.0025)  # four points a face average noise


def test_fit_reports_the_scan_and_stays_under_the_point_count():
    """fit_mesh on a small noisy scan with strays: data_report in the result (target frame)
    and the message; no more faces than the scan has points."""
    _, P = noisy_torus(3000, 0.01, n_out=30)
    res = fit_mesh(P * 2.0, time_budget=4.0)
    rep = res.data_report
    assert isinstance(rep, DataReport) and rep.n_points == 3030 and rep.n_outliers > 0
    assert 0.012 < rep.noise < 0.03  # noise 0.01 in the unit frame, the cloud scaled by 2
    assert "outliers removed" in res.message and "noise" in res.message
    assert res.mesh.n_faces <= rep.n_points
    assert res.summary()["data_report"]["n_points"] == 3030
