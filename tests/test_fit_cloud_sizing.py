"""How far the point-cloud fit refines (issue 25): samples a round, the vertex cap, the stall
test in units of the noise."""
from __future__ import annotations

import math

import numpy as np
import pytest

from geofit.fit import MeshFitOptions, Remeshing, fit_mesh
from geofit.fit import adaptive
from geofit.ops import sample_points_from_meshes
from geofit.shapes import torus


def torus_cloud(n=3000, noise=0.0, seed=0):
    m = torus(1.0, 0.35, 48, 24)
    P = sample_points_from_meshes(m, n, seed=seed)
    return P + np.random.default_rng(seed).normal(0.0, noise, P.shape)


def test_round_samples_of_a_mesh_target_are_unchanged_and_a_cloud_gets_12_a_vertex():
    """Mesh target: min(8000, max(2000, 4 V)); cloud: min(points, 20000, max(2000, s V)) with
    s = 12 unless given."""
    rs = adaptive._round_samples
    assert [rs(v, None) for v in (100, 1000, 5000)] == [2000, 4000, 8000]
    assert rs(1000, 50_000) == 12 * 1000
    assert rs(1000, 50_000, 8) == 8 * 1000
    assert rs(1000, 5000) == 5000                 # never more than the scan's points
    assert rs(100, 100_000) == 2000
    assert rs(5000, 100_000) == adaptive.CLOUD_MAX_SAMPLES


def test_refined_rounds_take_fewer_samples_a_vertex_on_precise_scans():
    """ceil(2 sigma^2 / (share * goal)) within [8, 12]: monotone in the noise, 12 at noise
    0.005 of the default goal, the floor on a clean scan."""
    f = adaptive.cloud_samples_per_vert
    goal = 3e-5
    got = [f(s, goal) for s in (0.0, 0.001, 0.003, 0.004, 0.005, 0.05)]
    assert got == sorted(got)
    assert got[0] == adaptive.CLOUD_MIN_SAMPLES_PER_VERT == 8
    assert f(0.005, goal) == f(0.05, goal) == adaptive.CLOUD_SAMPLES_PER_VERT == 12
    # between the bounds: the formula itself
    s = 0.0037
    assert f(s, goal) == math.ceil(2 * s * s / (adaptive.SAMPLE_NOISE_SHARE * goal)) == 10
    assert f(0.0037, 10 * goal) == 8             # a looser goal needs fewer


def test_a_cloud_fit_uses_12_samples_a_vertex_then_fewer_on_a_clean_scan():
    """The first round of a scan's fit draws 12 samples per vertex (at most the points); the
    refined rounds of a clean scan 8."""
    P = torus_cloud(3000, 0.002)
    res = fit_mesh(P, options=MeshFitOptions(n_iter=3, refine=Remeshing(max_rounds=1,
                                                                        n_faces=300)))
    st = res.stages[0]
    assert st["n_samples"] == min(len(P) - res.data_report.n_outliers,
                                  max(2000, 12 * st["n_verts"]))
    assert st["n_samples"] > 4 * st["n_verts"]  # more than a mesh target's rule
    P = torus_cloud(30_000)
    # a goal the first round misses (its estimate ~2.6e-5) that leaves the refined rounds 8 a
    # vertex at this scan's noise (~0.0009; 8 up to 0.0014)
    res = fit_mesh(P, options=MeshFitOptions(n_iter=5, refine=Remeshing(
        n_faces=600, chamfer_l2=5e-6, max_rounds=2)))
    assert adaptive.cloud_samples_per_vert(res.data_report.noise / res.scale, 5e-6) == 8
    assert len(res.stages) == 2
    assert [st["n_samples"] for st in res.stages] == [
        max(2000, 12 * res.stages[0]["n_verts"]), max(2000, 8 * res.stages[1]["n_verts"])]


def test_residual_gain_is_in_units_of_the_noise():
    """(sqrt(c0 / 2) - sqrt(c1 / 2)) / noise: 0.01 -> 0.008 a side at noise 0.01 is 0.2."""
    stages = [{"estimate": {"chamfer_l2": 2 * 0.01 ** 2}},
              {"estimate": {"chamfer_l2": 2 * 0.008 ** 2}}]
    assert adaptive._residual_gain(stages, 0.01) == pytest.approx(0.2, rel=1e-12)
    assert adaptive._residual_gain(stages[::-1], 0.02) == pytest.approx(-0.1, rel=1e-12)


def _hard_goal(max_rounds=3, n_faces=100):
    """Accuracy no scan reaches, so only the sizing rules stop the refinement."""
    return MeshFitOptions(n_iter=5, refine=Remeshing(n_faces=n_faces, chamfer_l2=1e-12,
                                                     fscore=1.0, max_rounds=max_rounds))


def test_refinement_stops_when_the_residual_no_longer_falls(monkeypatch):
    """With a stall threshold no round can beat, the fit stops after its second round and
    says why; without it, the same fit goes on refining."""
    P = torus_cloud(3000)
    monkeypatch.setattr(adaptive, "NOISE_STALL", math.inf)
    res = fit_mesh(P, options=_hard_goal())
    assert len(res.stages) == 2 and "noise level" in res.message
    monkeypatch.setattr(adaptive, "NOISE_STALL", -math.inf)
    res = fit_mesh(P, options=_hard_goal())
    assert len(res.stages) == 3 and "noise level" not in res.message


def test_refinement_stops_before_the_vertex_cap_of_a_cloud(monkeypatch):
    """A remesh that would pass what CLOUD_MAX_SAMPLES fit at the refined rounds' samples a
    vertex is not taken: the fit ends at the mesh it had."""
    P = torus_cloud(3000)
    # 100 vertices at 12 a vertex (the hard goal leaves no room for fewer)
    monkeypatch.setattr(adaptive, "CLOUD_MAX_SAMPLES", 1200)
    res = fit_mesh(P, options=_hard_goal())
    assert len(res.stages) == 1 and "12 a vertex" in res.message
    assert res.mesh.n_verts <= 100
    monkeypatch.setattr(adaptive, "CLOUD_MAX_SAMPLES", 80_000)
    assert len(fit_mesh(P, options=_hard_goal()).stages) > 1


def test_a_precise_scan_refines_past_the_unit_box_goal_to_its_noise_floor():
    """A precise scan's first round can meet the unit-box goal (3e-5) with a model residual
    well above the noise: the fit is held to 2.5 sigma^2 (or CLOUD_GOAL_SHARE of the goal)
    instead, and refines; a noisy scan's floor is unchanged (2.5 sigma^2 above 3e-5)."""
    P = torus_cloud(30_000)
    res = fit_mesh(P, options=MeshFitOptions(n_iter=5, refine=Remeshing(n_faces=600,
                                                                        max_rounds=2)))
    sigma = res.data_report.noise / res.scale
    goal = res.stages[0]["goal"]["chamfer_l2"]
    assert goal == pytest.approx(max(adaptive.CLOUD_GOAL_SHARE * 3e-5, 2.5 * sigma ** 2))
    assert goal < 3e-5
    assert res.stages[0]["estimate"]["chamfer_l2"] < 3e-5  # the old rule stopped here
    assert len(res.stages) == 2 and res.stages[1]["n_verts"] > res.stages[0]["n_verts"]
    P = torus_cloud(3000, 0.01)
    res = fit_mesh(P, options=MeshFitOptions(n_iter=3, refine=Remeshing(max_rounds=1,
                                                                        n_faces=300)))
    sigma = res.data_report.noise / res.scale
    goal = res.stages[0]["goal"]["chamfer_l2"]
    assert goal == pytest.approx(2.5 * sigma ** 2) and goal > 3e-5


def test_the_start_uses_more_points_of_a_precise_dense_scan_only():
    """start_points: n (spacing / (3 noise))^2 within [20,000, 50,000] and the scan's count:
    a noisy dense scan keeps about 20,000, a precise one all its points (up to 50,000)."""
    sp = adaptive.start_points
    assert sp(100_000, 0.0063, 0.0044) < 25_000            # noise 0.005: about today's 20,000
    assert sp(50_000, 0.0081, 0.0049) == adaptive.START_MIN_POINTS
    assert sp(50_000, 0.0064, 0.002) == 50_000              # noise 0.002: all of them
    assert sp(200_000, 0.004, 0.0) == adaptive.START_MAX_POINTS
    assert sp(5_000, 0.02, 0.007) == 5_000                  # never more than the scan has
    n = 200_000 * (0.005 / (3 * 0.004)) ** 2
    assert sp(200_000, 0.005, 0.004) == int(n)              # between the bounds: the formula
    assert [sp(100_000, 0.006, s) for s in (0.001, 0.002, 0.004, 0.008)] == sorted(
        [sp(100_000, 0.006, s) for s in (0.001, 0.002, 0.004, 0.008)], reverse=True)
