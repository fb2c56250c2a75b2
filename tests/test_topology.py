"""Topology report (geofit.ops.topology) and the procedural test shapes."""
import numpy as np
import pytest

from geofit import Mesh
from geofit.ops import TopologyReport, topology
from geofit.shapes import (
    TEST_SHAPES,
    double_torus,
    ico_sphere,
    open_cylinder,
    thin_plate,
    torus,
    two_spheres,
)


@pytest.mark.parametrize("make, genus, loops, parts", [
    (lambda: torus(), 1, 0, 1),
    (lambda: double_torus(40), 2, 0, 1),
    (lambda: open_cylinder(), 0, 2, 1),
    (lambda: two_spheres(2), 0, 0, 2),
    (lambda: thin_plate(0.1, 40), 0, 0, 1),
    (lambda: ico_sphere(2), 0, 0, 1),
])
def test_topology_counts(make, genus, loops, parts):
    """Genus, boundary loops and parts of shapes whose topology is known by construction."""
    r = topology(make())
    assert isinstance(r, TopologyReport)
    assert (r.genus, r.n_boundary_loops, r.n_components) == (genus, loops, parts)
    assert r.is_manifold and r.winding_consistent
    assert r.n_self_intersecting_pairs == 0 and r.n_degenerate_faces == 0
    assert r.euler_characteristic == 2 * parts - 2 * genus - loops


def test_topology_nonmanifold_and_self_intersection():
    """Three faces on one edge is non-manifold (genus undefined); two crossing squares intersect."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    r = topology(Mesh(v, f))
    assert r.n_nonmanifold_edges == 1 and r.genus == -1 and not r.is_manifold
    a = ico_sphere(1)
    b = Mesh(a.verts + [0.5, 0, 0], a.faces)
    crossing = Mesh(np.concatenate([a.verts, b.verts]), np.concatenate([a.faces, b.faces + 42]))
    r = topology(crossing)
    assert r.n_self_intersecting_pairs > 0 and "self-intersecting" in r.describe()
    assert topology(crossing, self_intersections=False).n_self_intersecting_pairs == -1


def test_topology_winding_and_degenerate():
    """A flipped face breaks winding consistency; a repeated corner is a degenerate face."""
    m = ico_sphere(1)
    f = m.faces.copy()
    f[0] = f[0, ::-1]
    assert not topology(Mesh(m.verts, f)).winding_consistent
    f = m.faces.copy()
    f[0, 1] = f[0, 0]
    assert topology(Mesh(m.verts, f), self_intersections=False).n_degenerate_faces >= 1


def test_topology_rejects_non_mesh():
    with pytest.raises(TypeError, match="mesh"):
        topology(np.zeros((3, 3)))


def test_test_shapes_deterministic_and_outward():
    """Each procedural shape is reproducible and encloses positive volume (outward faces)."""
    for name, make in TEST_SHAPES.items():
        a, b = make(), make()
        np.testing.assert_array_equal(a.verts, b.verts)
        np.testing.assert_array_equal(a.faces, b.faces)
        if name != "open_cylinder":
            v = a.verts[a.faces]
            vol = np.einsum("ij,ij->", v[:, 0], np.cross(v[:, 1], v[:, 2])) / 6
            assert vol > 0, name


@pytest.mark.parametrize("call, match", [
    (lambda: open_cylinder(n_around=2), "n_around"),
    (lambda: open_cylinder(radius=-1), "radius"),
    (lambda: thin_plate(thickness=2.0), "thickness"),
    (lambda: double_torus(resolution=4), "resolution"),
])
def test_shape_validation(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_face_components_connects_faces_through_shared_ids():
    """Faces sharing an id are one component, labels 0..k-1; masked-out faces are -1 and
    do not connect the others."""
    from geofit.ops.topology import face_components

    ids = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [7, 8, 9]])
    np.testing.assert_array_equal(face_components(ids), [0, 0, 0, 1])
    np.testing.assert_array_equal(face_components(ids, np.array([1, 0, 1, 1], bool)),
                                  [0, -1, 1, 2])
