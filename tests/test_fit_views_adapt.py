"""Tests for the curvature-adaptive remeshing of fit_mesh_to_views (``options.remesh_adapt``,
geofit.fit._views_adapt)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from geofit import Mesh, TexturesVertex, ico_sphere
from geofit.datasets import tutorial_views
from geofit.fit._views_adapt import _edge_curvature, _vertex_areas, adaptive_edge_lengths
from geofit.fit.views import ViewsFitOptions, fit_mesh_to_views
from geofit.shapes import thin_plate


def test_edge_curvature_of_a_sphere_is_its_inverse_radius_over_sqrt3():
    """On a finely meshed sphere of radius 2 the angle between neighbouring faces' normals over
    the edge length is about (1 / 2) / sqrt(3) (centroids e / sqrt(3) apart); it scales as
    1 / radius; a plane gives 0."""
    s = ico_sphere(4)
    k = _edge_curvature(s.update_verts(2.0 * s.verts))
    # a vertex takes the largest of its edges' values: biased up, within 35 %
    assert 0.5 / math.sqrt(3.0) < np.median(k) < 1.35 * 0.5 / math.sqrt(3.0)
    np.testing.assert_allclose(_edge_curvature(s.update_verts(4.0 * s.verts)), 0.5 * k,
                               rtol=1e-9)
    plane = Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]),
                 np.array([[0, 1, 2], [0, 2, 3]]))
    np.testing.assert_array_equal(_edge_curvature(plane), 0.0)


def test_vertex_areas_sum_to_the_surface_area():
    s = ico_sphere(2)
    np.testing.assert_allclose(_vertex_areas(s).sum(), s.face_areas.sum(), rtol=1e-12)


def test_adaptive_lengths_keep_the_face_measure_and_refine_the_rim():
    """A thin plate: its rims (high curvature) get shorter targets than its flat faces, and the
    expected face count sum a_v / l_v**2 is that of the uniform length (to the bisection's
    tolerance)."""
    m = thin_plate(0.06, 48).normalize().mesh
    length = 0.08
    lv = adaptive_edge_lengths(m, length, math.radians(30.0), longest=0.3, shortest=0.01)
    assert lv.shape == (m.n_verts,) and np.all(np.isfinite(lv)) and np.all(lv > 0)
    assert lv.min() >= 0.01 - 1e-15 and lv.max() <= 0.3 + 1e-15
    rim = np.abs(m.verts[:, [0, 2]]).max(axis=1) > 0.97
    flat = np.abs(m.verts[:, [0, 2]]).max(axis=1) < 0.8
    assert np.median(lv[rim]) < 0.5 * np.median(lv[flat])
    av = _vertex_areas(m)
    np.testing.assert_allclose(np.sum(av / lv ** 2), av.sum() / length ** 2, rtol=1e-3)
    # three grading sweeps: most neighbouring targets differ by at most the grade (1.5)
    e = m.edges
    ratio = np.maximum(lv[e[:, 0]] / lv[e[:, 1]], lv[e[:, 1]] / lv[e[:, 0]])
    assert np.mean(ratio <= 1.5 + 1e-9) > 0.9


def test_remesh_adapt_option_is_validated_and_runs():
    """options.remesh_adapt: degrees in [0, 180]; a small fit with it remeshes and finishes
    with a closed mesh."""
    m = ico_sphere(3)
    V = m.verts * np.array([0.9, 0.6, 0.5])
    obj = Mesh(V, m.faces, TexturesVertex(np.full((m.n_verts, 3), 0.6)))
    tr = tutorial_views(4, mesh=obj, num_views=6, image_size=24, num_held_out=0)
    for bad in (-1.0, 200.0, float("nan")):
        with pytest.raises(ValueError, match="remesh_adapt"):
            fit_mesh_to_views(tr, options=ViewsFitOptions(remesh_adapt=bad), progress=False)
    fit = fit_mesh_to_views(tr, options=ViewsFitOptions(
        remesh_adapt=30.0, silhouette_iters=4, rgb_iters=0, texture="vertex"), progress=False)
    assert fit.status != "nonfinite"
    assert fit.topology is not None and fit.topology.n_boundary_loops == 0
    assert np.all(np.isfinite(fit.mesh.verts))
