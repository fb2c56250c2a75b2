"""Vectorised remeshing (geofit.ops.remesh): topology kept, lengths reached, inputs checked."""
import numpy as np
import pytest

from geofit import Mesh
from geofit.ops import remesh, topology
from geofit.shapes import double_torus, ico_sphere, open_cylinder, plane, torus, two_spheres

SHAPES = {
    "torus": lambda: torus(1.0, 0.35, 32, 16),
    "double_torus": lambda: double_torus(40),
    "open_cylinder": lambda: open_cylinder(n_around=24, n_height=12),
    "two_spheres": lambda: two_spheres(2),
    "plane": lambda: plane(2.0, 8),
}


def _check_same_topology(before: Mesh, after: Mesh):
    a, b = topology(before), topology(after)
    assert (b.genus, b.n_components, b.n_boundary_loops) == (a.genus, a.n_components,
                                                              a.n_boundary_loops)
    assert b.n_nonmanifold_edges == 0 and b.n_nonmanifold_verts == 0
    assert b.winding_consistent
    assert b.n_degenerate_faces == 0
    # every vertex is used, indices in range
    assert np.unique(after.faces).size == after.n_verts


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_remesh_keeps_topology(name, factor):
    """Refining (factor 0.5) and coarsening (2) keep genus, parts, boundaries, manifoldness."""
    m = SHAPES[name]()
    L = float(m.edge_lengths.mean())
    r = remesh(m, factor * L, n_passes=4)
    _check_same_topology(m, r.mesh)
    mean = float(r.mesh.edge_lengths.mean())
    if factor < 1:
        assert r.n_split > 0 and mean < 0.75 * L
    else:
        assert r.n_collapse > 0 and mean > 1.05 * L
    assert r.target_length.shape == (r.mesh.n_verts,)


def test_remesh_per_vertex_length_refines_locally():
    """A small target length on one half of a sphere puts the new vertices there."""
    m = ico_sphere(2)
    L = float(m.edge_lengths.mean())
    lv = np.where(m.verts[:, 0] > 0, 0.4 * L, L)
    r = remesh(m, lv, n_passes=4)
    x = r.mesh.verts[:, 0]
    assert np.count_nonzero(x > 0.1) > 2 * np.count_nonzero(x < -0.1)
    _check_same_topology(m, r.mesh)


def test_remesh_vertices_stay_on_flat_surface():
    """Split midpoints and collapse midpoints of a plane stay in the plane; area is kept."""
    m = plane(2.0, 6)
    r = remesh(m, 0.15, n_passes=3)
    np.testing.assert_allclose(r.mesh.verts[:, 2], 0.0, atol=1e-15)
    np.testing.assert_allclose(r.mesh.face_areas.sum(), 4.0, rtol=1e-12)


def test_flip_improves_valence():
    """Flips alone never add vertices and lower the total valence excess."""
    m = torus(1.0, 0.35, 24, 12)
    # skew the valences by splitting once without flips
    m = remesh(m, 0.5 * float(m.edge_lengths.mean()), n_passes=1, flip=False).mesh
    r = remesh(m, 1.0, n_passes=2, split=False, collapse=False)
    dev = lambda mm: np.abs(mm.topology.degrees - 6).sum()  # noqa: E731
    assert r.n_flip > 0 and r.mesh.n_verts == m.n_verts and dev(r.mesh) < dev(m)


@pytest.mark.parametrize("kw, match", [
    ({"target_length": 0.0}, "target_length"),
    ({"target_length": np.ones(3)}, "target_length"),
    ({"target_length": np.nan}, "target_length"),
    ({"target_length": 0.1, "n_passes": 0}, "n_passes"),
])
def test_remesh_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        remesh(ico_sphere(1), **kw)
    with pytest.raises(TypeError, match="mesh"):
        remesh(np.zeros((3, 3)), 0.1)


def test_remesh_leaves_nonmanifold_vertex_alone():
    """Two cones touching at one vertex (a bowtie): the shared vertex is never collapsed."""
    a = ico_sphere(1)
    top = int(np.argmax(a.verts[:, 1]))
    v1 = a.verts - a.verts[top]
    v2 = -v1  # point-mirrored copy touching at the origin
    keep = np.arange(len(v1)) != top
    idx2 = np.full(len(v1), -1)
    idx2[keep] = len(v1) + np.arange(keep.sum())
    idx2[top] = top
    faces = np.concatenate([a.faces, idx2[a.faces]])
    m = Mesh(np.concatenate([v1, v2[keep]]), faces)
    assert topology(m).n_nonmanifold_verts == 1
    from geofit.ops.remesh import _boundary_verts

    protected = _boundary_verts(m)
    assert protected[top] and protected.sum() == 1  # the bowtie vertex, nothing else
    r = remesh(m, 2.0 * float(m.edge_lengths.mean()), n_passes=3)
    assert np.any(np.all(r.mesh.verts == 0.0, axis=1))  # the bowtie vertex stays in place
    t = topology(r.mesh)
    assert t.n_components == 1 and t.n_nonmanifold_edges == 0 and t.winding_consistent
