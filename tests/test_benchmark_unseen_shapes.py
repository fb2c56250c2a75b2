"""benchmarks/unseen_shapes.py (the analogues of the reviewers' public shapes) and the fix of
the flat sheet's start: each shape has the topology and form its docstring states, the group
``unseen`` is not part of the table's ``all``, and a zero-thickness sheet, whose visual hull is
thinner than the carving grid, starts the fit from the sphere enclosing it rather than from a
few fragments of hull."""
from __future__ import annotations

import numpy as np
import pytest
from _helpers import ROOT, benchmark_module

from geofit.ops import topology

SHAPES = benchmark_module("unseen_shapes")


@pytest.fixture(scope="module")
def built():
    return {name: make() for name, make in SHAPES.UNSEEN_SHAPES.items()}


# name -> (genus, boundary loops) as the module's docstring states them
EXPECTED = {"flat_sheet": (0, 1), "beetle": (0, 0), "eared_character": (0, 0),
            "cartoon_figure": (0, 0), "machine_part": (1, 0), "scan_blob": (0, 2)}


@pytest.mark.slow
def test_unseen_shapes_topology(built):
    """Each shape is one part with its stated genus and boundary loops (watertight ones have
    none), and its faces are oriented outwards (positive volume) where it is closed."""
    assert set(built) == set(EXPECTED)
    for name, mesh in built.items():
        t = topology(mesh, self_intersections=False)  # the sheet's own test checks them
        assert (t.genus, t.n_boundary_loops, t.n_components) == (*EXPECTED[name], 1), name
        assert mesh.verts.dtype == np.float64 and mesh.faces.dtype == np.int64
        if t.n_boundary_loops == 0:
            v = mesh.verts[mesh.faces]
            vol = np.einsum("ij,ij->", v[:, 0], np.cross(v[:, 1], v[:, 2])) / 6
            assert vol > 0, name


@pytest.mark.slow
def test_flat_sheet_is_a_zero_thickness_sheet(built):
    """The flat sheet lies exactly in z = 0, no triangle is folded (every normal is +Z) and
    none intersects another; it is elongated (x over y extent > 2)."""
    m = built["flat_sheet"]
    assert np.all(m.verts[:, 2] == 0.0)
    v = m.verts[m.faces]
    cz = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2]
    assert np.all(cz > 0)
    assert topology(m).n_self_intersecting_pairs == 0
    ext = m.verts.max(0) - m.verts.min(0)
    assert ext[0] > 2 * ext[1]


@pytest.mark.slow
def test_scan_blob_is_dense_noisy_and_seeded(built):
    """The scan has about 70 000 faces; its noise is seeded (same seed, same vertices;
    another seed, other vertices)."""
    m = built["scan_blob"]
    assert 60_000 <= m.n_faces <= 80_000
    other = SHAPES.scan_blob(resolution=40, seed=1)
    again = SHAPES.scan_blob(resolution=40, seed=1)
    np.testing.assert_array_equal(other.verts, again.verts)
    assert not np.array_equal(other.verts, SHAPES.scan_blob(resolution=40, seed=2).verts)


def test_unseen_group_not_in_all(monkeypatch):
    """``--shapes unseen`` names the six shapes; ``all`` (no names) stays the table's own."""
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    fv = benchmark_module("fit_views")
    assert list(fv.shape_factories(["unseen"])) == list(SHAPES.UNSEEN_SHAPES)
    assert not set(fv.shape_factories()) & set(SHAPES.UNSEEN_SHAPES)
    assert list(fv.shape_factories(["torus", "flat_sheet"])) == ["torus", "flat_sheet"]


def _sheet_views(size=64):
    from geofit import Mesh, TexturesVertex
    from geofit.datasets import tutorial_views

    m = SHAPES.flat_sheet(n_interior=400, n_boundary=120).normalize().mesh
    cols = 0.5 + 0.4 * np.sin(3.0 * m.verts + np.array([0.5, 1.5, 2.5]))
    m = Mesh(m.verts, m.faces, TexturesVertex(cols))
    return m, tutorial_views(4, mesh=m, num_views=20, image_size=size, num_held_out=4,
                             name="sheet")


def test_flat_hull_depth():
    """A zero-thickness sheet's visual hull is thinner than a grid step (twice ``depth_px``
    below ``voxel_size / pixel_size``); a sphere's is many steps deep."""
    from geofit import Mesh, TexturesVertex
    from geofit.datasets import tutorial_views
    from geofit.fit.init import visual_hull_mesh
    from geofit.shapes import ico_sphere

    _, ds = _sheet_views()
    h = visual_hull_mesh(ds.silhouettes, ds.cameras, fill_px=9.0)
    assert 2 * h.depth_px < h.voxel_size / h.pixel_size
    sphere = ico_sphere(3)
    sphere = Mesh(sphere.verts, sphere.faces, TexturesVertex(np.full((sphere.n_verts, 3), 0.5)))
    s = tutorial_views(4, mesh=sphere, num_views=20, image_size=64, num_held_out=0)
    hs = visual_hull_mesh(s.silhouettes, s.cameras, fill_px=9.0)
    assert hs.depth_px > 5 * hs.voxel_size / hs.pixel_size


@pytest.mark.slow
def test_flat_sheet_fit_starts_from_the_enclosing_sphere():
    """The default fit of a flat sheet starts from the sphere (the hull's fragments before the
    fix: held-out IoU 0.003 at 128 px), says why, and its result covers the held-out views
    (IoU > 0.7 after a few iterations)."""
    from geofit.fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views

    target, ds = _sheet_views()
    fit = fit_mesh_to_views(ds, options=ViewsFitOptions(silhouette_iters=15, textured_iters=5),
                            progress=False)
    assert fit.init == "sphere"
    assert "thinner than its carving grid" in fit.message
    ev = ViewsEvaluator(ds.held_out, target, n_samples=2000, taus=(0.01,))
    assert ev(fit.mesh, fit.colors)["iou"] > 0.7
