"""Time budgets bound what a fit does on its own (issue 26): the visual hull, held-out renders,
a stage's share; the defaults have no budget of their own. No timed assertion here: the
budgets on a loaded machine are measured by benchmarks/time_budget.py."""
from __future__ import annotations

import time

import numpy as np
import pytest

import geofit.fit._nerf_train as nerf_train
from geofit.datasets import tutorial_views
from geofit.fit import Clock, TimeUp, fit_mesh, fit_mesh_to_views, fit_nerf
from geofit.fit.nerf import NerfConfig
from geofit.shapes import torus


def test_clock_until_gives_a_stage_its_share_and_restores_the_deadline():
    """Inside until(t) the deadline is t (when earlier) and the words name the share; after
    it, the fit's deadline is back; a later limit changes nothing."""
    clock = Clock(deadline=30.0)
    with clock.until(0.0):
        time.sleep(0.005)
        assert clock.over() and clock.remaining() < 0
        with pytest.raises(TimeUp, match=r"this stage's share \(0 s\) of the time budget of 30"):
            clock.check()
    assert clock.deadline == 30.0 and not clock.over()
    with clock.until(60.0):
        assert clock.deadline == 30.0
    with Clock().until(None):
        pass


def test_fit_mesh_default_has_no_time_budget_of_its_own():
    """fit_mesh(target) stops on its own tests (no hidden 10 s budget that would make the
    result depend on the load); time_budget=inf is the same as none."""
    target = torus(1.0, 0.35, 24, 12)
    a = fit_mesh(target, evaluator=None, progress=False, seed=1)
    b = fit_mesh(target, evaluator=None, progress=False, seed=1, time_budget=float("inf"))
    assert a.status != "time_budget" and "time budget" not in a.message
    np.testing.assert_array_equal(a.mesh.verts, b.mesh.verts)
    assert a.wall_seconds >= a.seconds > 0 and a.total_cpu_seconds > 0


def test_views_budget_spent_on_the_hull_returns_the_sphere_and_says_so():
    """A budget used up while the visual hull is carved (checked between views) ends the fit
    there: the unfitted ico-sphere, status "time_budget", no solve and no colours, and the
    message says why."""
    ds = tutorial_views(4, num_views=4, image_size=32, num_held_out=0)
    fit = fit_mesh_to_views(ds, time_budget=1e-4, progress=False)
    assert fit.status == "time_budget" and fit.init == "sphere"
    assert fit.stages[0]["name"] == "init" and fit.stages[0]["status"] == "time_budget"
    assert "while carving the visual hull" in fit.message
    assert fit.n_iterations == 0 and fit.colors is None
    assert [s["status"] for s in fit.stages] == ["time_budget"] * 4  # init, sil., rgb, colours


def test_nerf_held_out_renders_stay_inside_the_budget(monkeypatch):
    """Held-out renders that do not fit are stopped (between chunks) and left out, and the
    message says which: the reference render may take a fifth of the budget, the final one
    what is left."""
    real = nerf_train.render_nerf

    def slow(*args, check=None, **kwargs):
        for _ in range(400):  # "chunks" of a render far longer than the budget
            time.sleep(0.01)
            if check is not None:
                check()
        return real(*args, check=check, **kwargs)

    monkeypatch.setattr(nerf_train, "render_nerf", slow)
    ds = tutorial_views(6, num_views=4, image_size=16, num_held_out=2)
    cfg = NerfConfig.scene()
    res = fit_nerf(ds, options=cfg, time_budget=1.5, progress=False)
    assert res.status in ("time_budget", "diverged") and res.n_iterations >= 1
    assert res.psnr is None and res.images is None
    assert "left out to keep the time budget: the untrained network's reference render" in \
        res.message and "the final held-out render" in res.message
