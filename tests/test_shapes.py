"""Procedural shapes: PyTorch3D ico_sphere parity, subdivision, tori, boxes, planes."""
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geofit import box, ico_sphere, plane, subdivide, tetrahedron, torus

REF = np.load(Path(__file__).parent / "data" / "ico_sphere.npz")


@pytest.mark.parametrize("level", [0, 1, 2, 3, 4])
def test_ico_sphere_matches_pytorch3d(level):
    """Same faces exactly and the same vertices to float32 precision as pytorch3d.utils.ico_sphere."""
    m = ico_sphere(level)
    assert m.n_verts == 10 * 4**level + 2 and m.n_faces == 20 * 4**level
    assert_array_equal(m.faces, REF[f"ico{level}_faces"])
    assert_allclose(m.verts, REF[f"ico{level}_verts"], rtol=0, atol=2e-7)


def test_ico_sphere_on_unit_sphere_and_outward():
    m = ico_sphere(3)
    assert_allclose(np.linalg.norm(m.verts, axis=1), 1.0, rtol=1e-14)
    assert np.all(np.einsum("ij,ij->i", m.face_cross, m.verts[m.faces].mean(1)) > 0)


def test_subdivide_features_and_orientation():
    """Midpoints carry averaged features; each face splits into four with the same orientation."""
    m = tetrahedron()
    feats = np.arange(4.0)[:, None]
    s, f = subdivide(m, feats)
    assert s.n_verts == 4 + 6 and s.n_faces == 16
    e = m.edges
    assert_allclose(f[4:, 0], 0.5 * (feats[e[:, 0], 0] + feats[e[:, 1], 0]))
    assert_allclose(s.face_areas.sum(), m.face_areas.sum(), rtol=1e-12)
    # every child normal points the same way as its parent
    parent = np.tile(np.arange(m.n_faces), 4)
    assert np.all(np.einsum("ij,ij->i", s.face_normals, m.face_normals[parent]) > 0.999)
    with pytest.raises(ValueError, match=r"feats: expected shape \(4, C\)"):
        subdivide(m, np.zeros((3, 1)))


def test_closed_shapes_enclose_positive_volume():
    """Outward orientation: the divergence-theorem volume is positive and correct."""
    for mesh, vol in ((box((1, 2, 3)), 6.0), (tetrahedron(), 8 / (9 * np.sqrt(3)))):
        c = mesh.verts[mesh.faces].mean(1)
        assert_allclose((c * mesh.face_cross).sum() / 6, vol, rtol=1e-12)
    t = torus(1.0, 0.25, 64, 32)
    c = t.verts[t.faces].mean(1)
    assert_allclose((c * t.face_cross).sum() / 6, 2 * np.pi**2 * 1.0 * 0.25**2, rtol=0.02)
    assert t.topology.is_watertight and t.topology.euler_characteristic == 0


def test_plane_normals_and_counts():
    p = plane(2.0, 4, z=0.5)
    assert p.n_verts == 25 and p.n_faces == 32
    assert_allclose(p.face_normals, np.broadcast_to([0, 0, 1.0], (32, 3)))
    assert_allclose(p.verts[:, 2], 0.5)
    assert_allclose(p.face_areas.sum(), 4.0)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: ico_sphere(-1), r"level: expected an integer in \[0, 8\]"),
        (lambda: ico_sphere(1.5), "level"),
        (lambda: ico_sphere(True), "level"),
        (lambda: torus(1.0, 2.0), "minor_radius < major_radius"),
        (lambda: torus(n_major=2), "n_major: expected an integer >= 3"),
        (lambda: torus(n_minor=2.5), "n_minor"),
        (lambda: box((1, 0, 1)), "size: expected three finite numbers > 0"),
        (lambda: plane(n=0), "n: expected an integer >= 1"),
        (lambda: plane(size=-1), "size: expected a finite number > 0"),
    ],
)
def test_shape_validation(call, match):
    with pytest.raises(ValueError, match=match):
        call()
