"""Initial meshes from the data (geofit.fit.init) and the remeshing fit (geofit.fit.adaptive),
the default recipe of fit_mesh."""
import math

import numpy as np
import pytest

from geofit import Mesh
from geofit.fit import MeshFitOptions, MeshFitResult, Remeshing, fit_mesh
from geofit.fit.adaptive import refine_lengths
from geofit.fit.init import decimate, initial_mesh, mesh_from_occupancy
from geofit.metrics import evaluate_mesh
from geofit.ops import topology
from geofit.shapes import double_torus, ico_sphere, open_cylinder, torus, two_spheres


@pytest.mark.parametrize("make", [lambda: torus(), lambda: double_torus(40),
                                  lambda: open_cylinder(), lambda: two_spheres(2)])
def test_decimate_keeps_topology(make):
    """Quadric decimation of the procedural shapes keeps genus, parts and boundary loops."""
    m = make()
    d = decimate(m, 300)
    a, b = topology(m), topology(d)
    assert d.n_faces <= 300
    assert (b.genus, b.n_components, b.n_boundary_loops) == (a.genus, a.n_components,
                                                              a.n_boundary_loops)


def test_mesh_from_occupancy_ball():
    """Marching cubes of a ball's occupancy: closed, genus 0, radius within a voxel."""
    n, h = 32, 1.0 / 15
    t = (np.arange(n) - (n - 1) / 2) * h
    X, Y, Z = np.meshgrid(t, t, t, indexing="ij")
    occ = (X ** 2 + Y ** 2 + Z ** 2 < 0.7 ** 2).astype(float)
    m = mesh_from_occupancy(occ, (t[0], t[0], t[0]), h)
    r = topology(m)
    assert (r.genus, r.n_components, r.n_boundary_loops) == (0, 1, 0)
    np.testing.assert_allclose(np.linalg.norm(m.verts, axis=1), 0.7, atol=h)
    v = m.verts[m.faces]
    assert np.einsum("ij,ij->", v[:, 0], np.cross(v[:, 1], v[:, 2])) > 0  # outward
    assert mesh_from_occupancy(occ, (t[0],) * 3, h, n_faces=200).n_faces <= 200
    with pytest.raises(ValueError, match="occupancy"):
        mesh_from_occupancy(np.zeros((4, 4)), (0, 0, 0), h)
    with pytest.raises(ValueError, match="level"):
        mesh_from_occupancy(np.zeros((4, 4, 4)), (0, 0, 0), h)


def test_initial_mesh_choices():
    """auto -> decimated target; sphere -> ico-sphere; int -> that level; Mesh -> as given."""
    t = torus()
    assert initial_mesh("auto", t, n_faces=400).name == "target"
    assert initial_mesh("auto", None).name == "sphere"
    assert initial_mesh("sphere", t, sphere_level=1).mesh.n_verts == 42
    assert initial_mesh(2, t).mesh.n_verts == 162
    s = ico_sphere(1)
    assert initial_mesh(s, t).mesh is s
    with pytest.raises(ValueError, match="init"):
        initial_mesh("poisson", t)
    with pytest.raises(ValueError, match="init"):
        initial_mesh("target", None)
    with pytest.raises(ValueError, match="n_faces"):
        decimate(t, 2)


def test_refine_lengths_shorter_where_error_is_large():
    """Edges with error above eps ask for shorter lengths, below eps for longer, clipped."""
    m = ico_sphere(2)
    err = np.where(m.verts[m.edges[:, 0], 0] > 0, 1e-2, 1e-6)
    lv = refine_lengths(m, err, 1e-3)
    le = m.edge_lengths.mean()
    assert lv[m.verts[:, 0] > 0.3].max() < le and lv[m.verts[:, 0] < -0.3].min() > le
    assert lv.min() >= 0.5 * m.edge_lengths.min() - 1e-12


def test_fit_mesh_adaptive_genus_two():
    """The default fit of a genus-2 target keeps genus 2 and reaches F@0.01 >= 0.95."""
    target = double_torus(48)
    res = fit_mesh(target, options=MeshFitOptions(
        n_iter=10, refine=Remeshing(n_faces=1200, max_rounds=2)), evaluator=None,
        time_budget=math.inf)
    assert res.init == "target" and res.topology.genus == 2
    m = evaluate_mesh(res.mesh, target, n_samples=20000, normalize=True)
    assert m.fscore[0.01] >= 0.95
    assert res.n_verts == res.mesh.n_verts and "genus 2" in res.message
    assert res.status in ("converged", "max_iter")


def test_fit_mesh_adaptive_sphere_init_and_remesh():
    """From an ico-sphere the fit remeshes (the vertex count changes) and says it used a sphere."""
    target = ico_sphere(3).update_verts(ico_sphere(3).verts * [1.0, 0.6, 0.8])
    res = fit_mesh(target, options=MeshFitOptions(
        init=1, n_iter=15, refine=Remeshing(max_rounds=2, chamfer_l2=1e-9, fscore=1.0)),
        evaluator=None, time_budget=math.inf)
    assert res.init == "sphere"
    assert "remesh" in res.stages[0] and res.n_verts != 42
    r = res.topology
    assert r.genus == 0 and r.is_manifold and r.winding_consistent


@pytest.mark.parametrize("make, match", [
    (lambda: {"options": MeshFitOptions(refine=Remeshing(n_faces=1))}, "n_faces"),
    (lambda: {"options": MeshFitOptions(refine=Remeshing(max_rounds=0))}, "max_rounds"),
    (lambda: {"options": MeshFitOptions(refine=Remeshing(fscore=2.0))}, "fscore"),
    (lambda: {"options": MeshFitOptions(large_steps=-1.0)}, "large_steps"),
    (lambda: {"options": MeshFitOptions(large_steps=0.0)}, "large_steps"),
    (lambda: {"options": MeshFitOptions(method="sgd")}, "method"),
    (lambda: {"options": MeshFitOptions(n_stages=2)}, "n_stages"),
    (lambda: {"evaluator": "best"}, "evaluator"),
    (lambda: {"options": MeshFitOptions(weights={"chamfer": 0.0})}, "chamfer"),
])
def test_fit_mesh_default_recipe_validation(make, match):
    """Every invalid setting of the remeshing fit raises a ValueError naming it."""
    with pytest.raises(ValueError, match=match):
        fit_mesh(ico_sphere(1), **make())
    with pytest.raises(TypeError, match="target"):
        fit_mesh("mesh.obj")
    with pytest.raises(ValueError, match="target"):
        fit_mesh(Mesh(np.zeros((3, 3)), np.array([[0, 1, 2]])))


def test_docstring_examples():
    """The Examples sections of the remeshing, topology and adaptive-fit modules run."""
    import doctest
    import importlib

    for name in ("geofit.ops.remesh", "geofit.ops.topology", "geofit.fit.adaptive"):
        mod = importlib.import_module(name)  # the package exports functions of the same name
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0 and result.attempted > 0, mod.__name__


def test_fit_mesh_default_is_adaptive():
    """fit_mesh(target) runs the remeshing fit from the target; recipe='sphere' does not, and
    options of the default recipe keep it (no hidden switch)."""
    target = torus(1.0, 0.35, 32, 16)
    res = fit_mesh(target, evaluator=None, time_budget=3.0)
    assert isinstance(res, MeshFitResult) and res.init == "target"
    assert res.topology.genus == 1 and res.recipe == "default"
    res = fit_mesh(target, options=MeshFitOptions(n_iter=2), evaluator=None, time_budget=3.0)
    assert res.init == "target" and res.topology is not None
    res = fit_mesh(target, recipe="sphere", options=MeshFitOptions(n_iter=2, n_stages=1),
                   evaluator=None, progress=False)
    assert res.topology is None and res.n_verts == 2562
    with pytest.raises(ValueError, match="init"):
        fit_mesh(target, recipe="sphere", options=MeshFitOptions(init="poisson"))


def test_visual_hull_mesh_of_a_ball():
    """The hull of a ball seen from 8 directions is one closed genus-0 part around the ball."""
    from geofit.datasets import render_views
    from geofit.fit.init import visual_hull_mesh

    from geofit.structures import TexturesVertex

    s = ico_sphere(3)
    ball = Mesh(0.6 * s.verts, s.faces, TexturesVertex(np.full((s.n_verts, 3), 0.7)))
    ds = render_views(ball, [0, 45, 90, 135, 180, 225, 270, 315], [0, 30, 60, -30, 0, -60, 30, 0],
                      image_size=64)
    h = visual_hull_mesh(ds.silhouettes, ds.cameras, edge_px=2.0).mesh
    r = topology(h)
    assert (r.genus, r.n_components, r.n_boundary_loops) == (0, 1, 0)
    radius = np.linalg.norm(h.verts, axis=1)
    assert radius.min() > 0.58 and radius.max() < 0.8  # contains the ball, a few pixels loose
    with pytest.raises(ValueError, match="edge_px"):
        visual_hull_mesh(ds.silhouettes, ds.cameras, edge_px=0.0)
    with pytest.raises(ValueError, match="threshold"):
        visual_hull_mesh(ds.silhouettes, ds.cameras, threshold=1.0)
    with pytest.raises(ValueError, match="silhouettes"):
        visual_hull_mesh(ds.silhouettes[:3], ds.cameras)
    with pytest.raises(ValueError, match="empty"):
        visual_hull_mesh(np.zeros_like(ds.silhouettes), ds.cameras)


def test_fit_mesh_adaptive_budget_used_up_while_building_the_objective(monkeypatch):
    """The adaptive fit's solve gets what is left of the budget after its objective is built."""
    import time

    import geofit.fit.adaptive as fa

    class Slow(fa.MeshObjective):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            time.sleep(0.4)

    monkeypatch.setattr(fa, "MeshObjective", Slow)
    res = fit_mesh(torus(1.0, 0.35, 24, 12), time_budget=0.3, evaluator=None, progress=False)
    assert res.status == "time_budget" and res.n_evaluations <= 2  # no time left to iterate
