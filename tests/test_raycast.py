"""Tests for geofit.raycast: Embree ray casting against a numpy reference and closed forms,
and float64 closest points against brute force."""
import numpy as np
import pytest

from geofit import Mesh, Meshes, ico_sphere, plane, torus
from geofit.raycast import (ClosestPoints, PointToMeshDistance, RayCaster, RayHits,
                            closest_point_on_triangles, intersect_rays_triangles)


# ---------------------------------------------------------------------------- helpers
def random_soup(seed, n_faces=150, center=(0.0, 0.0, 0.0), scale=1.0):
    """A random triangle soup (many intersecting triangles) in a cube around ``center``."""
    rng = np.random.default_rng(seed)
    V = rng.uniform(-1, 1, (3 * n_faces, 3)) * scale + np.asarray(center)
    F = np.arange(3 * n_faces).reshape(-1, 3)
    return Mesh(V, F)


def random_rays(seed, n, center=(0.0, 0.0, 0.0), scale=1.0):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2, 2, (n, 3)) * scale + np.asarray(center)
    d = rng.normal(size=(n, 3))
    return o, d


def brute_closest(P, V, F, chunk=200):
    """Closest point by evaluating every (point, face) pair (vectorised in chunks of faces)."""
    best = np.full(len(P), np.inf)
    best_q = np.zeros_like(P)
    for a in range(0, len(F), chunk):  # chunks of faces
        f = F[a:a + chunk]
        n = len(f)
        PP = np.repeat(P, n, axis=0)
        A, B, C = (np.tile(V[f[:, i]], (len(P), 1)) for i in range(3))
        Q, _ = closest_point_on_triangles(PP, A, B, C)
        d = np.linalg.norm(PP - Q, axis=1).reshape(len(P), n)
        j = np.argmin(d, axis=1)
        dj = d[np.arange(len(P)), j]
        better = dj < best
        best[better] = dj[better]
        best_q[better] = Q.reshape(len(P), n, 3)[np.arange(len(P)), j][better]
    return best, best_q


def segment_closest(P, a, b):
    ab = b - a
    L2 = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", P - a, ab) / np.where(L2 > 0, L2, 1.0), 0, 1)
    return a + t[:, None] * ab


def closest_by_candidates(P, A, B, C):
    """A different algorithm: in-plane projection if it falls inside, else the best of the
    three edge segments."""
    n = np.cross(B - A, C - A)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    proj = P - np.einsum("ij,ij->i", P - A, n)[:, None] * n
    inside = np.ones(len(P), bool)
    for X, Y in ((A, B), (B, C), (C, A)):
        inside &= np.einsum("ij,ij->i", np.cross(Y - X, proj - X), n) >= 0
    cands = np.stack([segment_closest(P, A, B), segment_closest(P, B, C),
                      segment_closest(P, C, A)], axis=1)
    dist = np.linalg.norm(cands - P[:, None], axis=2)
    out = cands[np.arange(len(P)), np.argmin(dist, axis=1)]
    out[inside] = proj[inside]
    return out


# ---------------------------------------------------------------------------- ray casting
@pytest.mark.parametrize("seed,center,scale", [(0, (0, 0, 0), 1.0), (1, (1e3, -2e3, 5e2), 10.0),
                                               (2, (0, 0, 0), 1e-3)])
def test_cast_matches_numpy_reference(seed, center, scale):
    """Embree and the brute-force reference agree on hit/miss, face and (refined) t."""
    m = random_soup(seed, center=center, scale=scale)
    o, d = random_rays(seed + 10, 4000, center=center, scale=scale)
    hits = RayCaster(m).cast(o, d)
    ref = intersect_rays_triangles(o, d, m.verts, m.faces)
    assert 0.05 < ref.hit.mean() < 0.95
    assert np.mean(hits.hit == ref.hit) >= 0.999
    both = hits.hit & ref.hit
    assert np.all(hits.mesh_id[hits.hit] == 0)
    same = both & (hits.face_id == ref.face_id)
    assert same.sum() >= 0.999 * both.sum()
    np.testing.assert_allclose(hits.t[same], ref.t[same], rtol=1e-9, atol=0)
    np.testing.assert_allclose(hits.bary[same], ref.bary[same], rtol=0, atol=1e-9)
    # where the faces differ (a shared edge or a float32 tie) the depth still agrees closely
    np.testing.assert_allclose(hits.t[both], ref.t[both], rtol=1e-5)
    # misses are inf / -1 / 0
    miss = ~hits.hit
    assert np.all(np.isinf(hits.t[miss])) and np.all(hits.face_id[miss] == -1)
    assert np.all(hits.mesh_id[miss] == -1) and np.all(hits.bary[miss] == 0)


def test_hit_points_lie_on_hit_triangle():
    """Barycentrics of the hit triangle reproduce o + t d, and they are a convex combination."""
    m = random_soup(3)
    o, d = random_rays(4, 3000)
    hits = RayCaster(m).cast(o, d)
    h = hits.hit
    tri = m.verts[m.faces[hits.face_id[h]]]
    p_bary = np.einsum("ki,kij->kj", hits.bary[h], tri)
    np.testing.assert_allclose(p_bary, hits.points(o, d)[h], atol=1e-9)
    assert np.all(hits.bary[h] >= 0)
    np.testing.assert_allclose(hits.bary[h].sum(axis=1), 1.0, atol=1e-12)
    assert np.all(hits.points(o, d)[~h] == 0)


def test_plane_t_exact():
    """Against the plane Z = z0, t = (z0 - oz) / dz exactly (float64 refinement)."""
    z0 = 0.3
    rng = np.random.default_rng(5)
    r = 2000
    o = np.column_stack([rng.uniform(-0.5, 0.5, (r, 2)), rng.uniform(0.5, 50.0, r)])
    target = np.column_stack([rng.uniform(-1.9, 1.9, (r, 2)), np.full(r, z0)])
    d = (target - o) * rng.uniform(0.1, 10.0, (r, 1))  # any length
    hits = RayCaster(plane(size=4.0, n=3, z=z0)).cast(o, d)
    assert hits.hit.all()
    np.testing.assert_allclose(hits.t, (z0 - o[:, 2]) / d[:, 2], rtol=1e-12, atol=0)


def test_unit_sphere_hits_between_inradius_and_one():
    """Rays from the centre of ico_sphere(5) all hit, at a distance between the polyhedron's
    smallest face-plane distance and 1 (its vertices lie on the unit sphere)."""
    s = ico_sphere(5)
    tri = s.verts[s.faces]
    inradius = np.min(np.einsum("ij,ij->i", s.face_normals, tri[:, 0]))
    assert 0.999 < inradius < 1.0
    rng = np.random.default_rng(6)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = RayCaster(s).cast(np.zeros((len(d), 3)), d)
    assert hits.hit.all()
    assert np.all(hits.t >= inradius - 1e-12) and np.all(hits.t <= 1 + 1e-12)
    # from outside: a ray aimed at the centre from distance 3 enters at t = 3 - (about 1)
    hits = RayCaster(s).cast(3 * d, -d)
    assert np.all(hits.t >= 2 - 1e-12) and np.all(hits.t <= 3 - inradius + 1e-12)


def test_direction_length_scales_t():
    """t is in units of the direction's length: scaling directions by k divides t by k."""
    m = random_soup(7)
    o, d = random_rays(8, 2000)
    rc = RayCaster(m)
    a, b = rc.cast(o, d), rc.cast(o, 7.5 * d)
    assert np.array_equal(a.hit, b.hit)
    np.testing.assert_allclose(b.t[a.hit], a.t[a.hit] / 7.5, rtol=1e-12)


def test_batch_reports_mesh_id_and_packed_face_id():
    """In a batch (with an empty mesh in it) each ray reports the mesh it hit."""
    centers = np.array([[-3.0, 0, 0], [0.0, 0, 0], [4.0, 0, 0]])
    s = ico_sphere(2)
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    batch = Meshes([s.offset_verts(centers[0]), empty, s.offset_verts(centers[1]),
                    ico_sphere(3).offset_verts(centers[2])])
    rc = RayCaster(batch)
    rng = np.random.default_rng(9)
    which = rng.integers(0, 3, 500)
    o = centers[which] + np.column_stack([rng.uniform(-0.5, 0.5, (500, 2)), np.full(500, 5.0)])
    d = np.tile([0.0, 0.0, -1.0], (500, 1))
    hits = rc.cast(o, d)
    assert hits.hit.all()
    np.testing.assert_array_equal(hits.mesh_id, np.array([0, 2, 3])[which])
    # face_id indexes the mesh's own faces; packed_face_id indexes faces_packed()
    pf = rc.packed_face_id(hits)
    fp, vp = batch.faces_packed(), batch.verts_packed()
    for i in range(len(batch)):  # loop over batch members
        sel = hits.mesh_id == i
        if sel.any():
            np.testing.assert_allclose(vp[fp[pf[sel]]], batch[i].verts[batch[i].faces[
                hits.face_id[sel]]])
    assert rc.n_meshes == 4 and rc.n_faces == 2 * 320 + 1280
    miss = rc.cast([[0.0, 10.0, 0.0]], [[0.0, 1.0, 0.0]])
    assert rc.packed_face_id(miss)[0] == -1


def test_tnear_tfar_respected():
    """A ray through the unit sphere from z=-3: entry just after t=2, exit just before t=4; tnear skips the
    entry, tfar cuts it off, per-ray arrays work, and hits always satisfy tnear <= t <= tfar."""
    rc = RayCaster(ico_sphere(4))
    o = np.tile([0.01, 0.02, -3.0], (4, 1))
    d = np.tile([0.0, 0.0, 1.0], (4, 1))
    hits = rc.cast(o, d, tnear=[0.0, 2.5, 0.0, 0.0], tfar=[np.inf, np.inf, 1.9, 2.5])
    assert 2.0 <= hits.t[0] < 2.01 and 3.99 < hits.t[1] <= 4.0
    assert not hits.hit[2] and hits.t[3] == hits.t[0]
    rng = np.random.default_rng(12)
    o = rng.uniform(-2, 2, (3000, 3))
    d = rng.uniform(-0.7, 0.7, (3000, 3)) - o  # aimed into the sphere
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tn = rng.uniform(0, 2, 3000)
    tf = tn + rng.uniform(0, 3, 3000)
    rc = RayCaster(ico_sphere(2))
    hits = rc.cast(o, d, tnear=tn, tfar=tf)
    assert 0.1 < hits.hit.mean() < 0.9
    h = hits.hit
    assert np.all(hits.t[h] >= tn[h] * (1 - 1e-6)) and np.all(hits.t[h] <= tf[h])
    ref = intersect_rays_triangles(o, d, rc.meshes[0].verts, rc.meshes[0].faces,
                                   tnear=tn, tfar=tf)
    assert np.mean(ref.hit == hits.hit) >= 0.999
    both = ref.hit & hits.hit
    np.testing.assert_allclose(hits.t[both], ref.t[both], rtol=1e-9)


def test_update_verts_moves_hits():
    """Lifting a plane by dz shortens every downward hit by exactly dz (one mesh, list and
    packed forms for a batch)."""
    p = plane(size=2.0, n=2)
    rc = RayCaster(p)
    rng = np.random.default_rng(13)
    o = np.column_stack([rng.uniform(-0.9, 0.9, (100, 2)), np.full(100, 2.0)])
    d = np.tile([0.0, 0.0, -1.0], (100, 1))
    t0 = rc.cast(o, d).t
    assert rc.update_verts(p.verts + [0, 0, 0.25]) is rc
    np.testing.assert_allclose(rc.cast(o, d).t, t0 - 0.25, rtol=1e-14)
    assert rc.meshes[0].verts[0, 2] == 0.25
    rcb = RayCaster([p, p.offset_verts([5.0, 0, 0])])
    rcb.update_verts([p.verts + [0, 0, 0.5], p.verts + [5.0, 0, -0.5]])
    np.testing.assert_allclose(rcb.cast(o, d).t, t0 - 0.5, rtol=1e-14)
    np.testing.assert_allclose(rcb.cast(o + [5.0, 0, 0], d).t, t0 + 0.5, rtol=1e-14)
    rcb.update_verts(np.concatenate([p.verts, p.verts + [5.0, 0, 1.0]]))
    np.testing.assert_allclose(rcb.cast(o + [5.0, 0, 0], d).t, t0 - 1.0, rtol=1e-14)


def test_occluded_agrees_with_cast():
    """A segment is occluded exactly when its first hit lies before tfar."""
    m = random_soup(14)
    o, d = random_rays(15, 5000)
    rc = RayCaster(m)
    tfar = np.random.default_rng(16).uniform(0.1, 3.0, 5000)
    occ = rc.occluded(o, d, tfar)
    hits = rc.cast(o, d)
    expect = hits.t <= tfar
    clear = np.abs(hits.t - tfar) > 1e-5 * tfar  # float32 decides ties at tfar
    assert 0.05 < expect.mean() < 0.95
    np.testing.assert_array_equal(occ[clear], expect[clear])
    np.testing.assert_array_equal(rc.occluded(o, d), hits.hit)
    # tnear removes occluders before it
    assert not rc.occluded([[0, 0, -3.0]], [[0, 0, 1.0]], 10.0, tnear=9.0)[0]


def test_threads_identical_to_single_thread():
    """Splitting rays over threads does not change any result."""
    m = ico_sphere(3)
    o, d = random_rays(17, 30001)
    one = RayCaster(m, n_threads=1)
    two = RayCaster(m, n_threads=2, parallel_min=100)
    three = RayCaster(m, n_threads=3, parallel_min=100)
    a, b, c = one.cast(o, d, tfar=2.0), two.cast(o, d, tfar=2.0), three.cast(o, d, tfar=2.0)
    for f in RayHits._fields:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        np.testing.assert_array_equal(getattr(a, f), getattr(c, f))
    np.testing.assert_array_equal(one.occluded(o, d, 2.0), two.occluded(o, d, 2.0))


def test_empty_ray_batch():
    """Zero rays give zero-length results of the right shapes."""
    rc = RayCaster(ico_sphere(1))
    hits = rc.cast(np.zeros((0, 3)), np.zeros((0, 3)))
    assert hits.t.shape == (0,) and hits.bary.shape == (0, 3) and hits.face_id.dtype == np.int64
    assert rc.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
    ref = intersect_rays_triangles(np.zeros((0, 3)), np.zeros((0, 3)), np.eye(3), [[0, 1, 2]])
    assert ref.t.shape == (0,)


def test_reference_edge_ties_and_parallel_rays():
    """The reference hits closed edges (lowest face wins) and never hits a parallel face."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    F = np.array([[0, 1, 2], [1, 3, 2]])
    hits = intersect_rays_triangles([[0.5, 0.5, 1], [0.2, 0.2, 0]], [[0, 0, -1], [1, 0, 0]], V, F)
    assert hits.face_id.tolist() == [0, -1] and hits.t[0] == 1.0


# ---------------------------------------------------------------------------- validation
def test_raycaster_validation():
    rc = RayCaster(ico_sphere(1))
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    with pytest.raises(TypeError, match="meshes"):
        RayCaster(np.eye(3))
    with pytest.raises(ValueError, match="at least one face"):
        RayCaster(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
    with pytest.raises(ValueError, match="at least one face"):
        RayCaster(Meshes([]))
    with pytest.raises(ValueError, match="n_threads"):
        RayCaster(ico_sphere(1), n_threads=0)
    with pytest.raises(ValueError, match="parallel_min"):
        RayCaster(ico_sphere(1), parallel_min=0)
    with pytest.raises(ValueError, match="origins"):
        rc.cast(np.zeros((2, 2)), d)
    with pytest.raises(ValueError, match="directions"):
        rc.cast(o, np.ones((3, 3)))
    with pytest.raises(ValueError, match="non-zero"):
        rc.cast(o, [[0, 0, 0], [1, 0, 0]])
    with pytest.raises(ValueError, match="finite"):
        rc.cast([[np.nan, 0, 0], [0, 0, 0]], d)
    with pytest.raises(ValueError, match="tnear"):
        rc.cast(o, d, tnear=-1.0)
    with pytest.raises(ValueError, match="tnear"):
        rc.cast(o, d, tnear=np.inf)
    with pytest.raises(ValueError, match="tnear"):
        rc.cast(o, d, tnear="near")
    with pytest.raises(ValueError, match="tfar"):
        rc.cast(o, d, tnear=2.0, tfar=1.0)
    with pytest.raises(ValueError, match="tfar"):
        rc.cast(o, d, tfar=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="tfar"):
        rc.cast(o, d, tfar=np.nan)
    with pytest.raises(ValueError, match="directions"):
        rc.occluded(o, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="verts"):
        rc.update_verts(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="list of 1"):
        rc.update_verts([np.zeros((42, 3)), np.zeros((42, 3))])
    with pytest.raises(ValueError, match=r"verts\[0\]"):
        rc.update_verts([np.zeros((41, 3))])


def test_reference_validation():
    V, F = np.eye(3), [[0, 1, 2]]
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    with pytest.raises(ValueError, match="directions"):
        intersect_rays_triangles(o, np.ones((1, 3)), V, F)
    with pytest.raises(ValueError, match="non-zero"):
        intersect_rays_triangles(o, np.zeros((2, 3)), V, F)
    with pytest.raises(ValueError, match="faces"):
        intersect_rays_triangles(o, d, V, [[0, 1, 3]])
    with pytest.raises(ValueError, match="tnear"):
        intersect_rays_triangles(o, d, V, F, tnear=-0.5)
    with pytest.raises(ValueError, match="tfar"):
        intersect_rays_triangles(o, d, V, F, tnear=1.0, tfar=0.5)
    with pytest.raises(ValueError, match="chunk_pairs"):
        intersect_rays_triangles(o, d, V, F, chunk_pairs=0)


# ---------------------------------------------------------------------------- closest points
def test_closest_point_on_triangles_matches_candidate_algorithm():
    """Ericson's region test agrees with 'projection if inside, else best edge point' in all
    seven regions, and its barycentrics reproduce the point."""
    rng = np.random.default_rng(20)
    k = 20000
    A, B, C = (rng.normal(size=(k, 3)) for _ in range(3))
    P = rng.normal(size=(k, 3)) * 2
    Q, w = closest_point_on_triangles(P, A, B, C)
    np.testing.assert_allclose(Q, closest_by_candidates(P, A, B, C), atol=1e-9)
    np.testing.assert_allclose(w[:, 0:1] * A + w[:, 1:2] * B + w[:, 2:3] * C, Q, atol=1e-12)
    assert np.all(w >= 0) and np.allclose(w.sum(axis=1), 1.0)
    regions = {(wi > 0).tobytes() for wi in w}  # which barycentrics are non-zero
    assert len(regions) == 7


def test_closest_point_degenerate_triangles_finite():
    """Zero-area triangles (collinear, or all corners equal) give finite points on the hull."""
    P = np.array([[0.3, 1.0, 0.0], [5.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    A = np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 1, 1]])
    B = np.array([[1.0, 0, 0], [2.0, 0, 0], [1.0, 1, 1]])
    C = np.array([[2.0, 0, 0], [1.0, 0, 0], [1.0, 1, 1]])
    Q, w = closest_point_on_triangles(P, A, B, C)
    assert np.all(np.isfinite(Q)) and np.all(np.isfinite(w))
    np.testing.assert_allclose(Q, [[0.3, 0, 0], [2.0, 0, 0], [1.0, 1, 1]], atol=1e-15)


def test_closest_point_squared_distance_gradient_finite_difference():
    """dD/dP = 2 (P - Q) and dD/dA_j = -2 w_j (P - Q) for D = |P - Q|^2 (central differences,
    float64, in the face, edge and vertex regions)."""
    A = np.array([[0.0, 0, 0]])
    B = np.array([[1.0, 0.1, 0]])
    C = np.array([[0.2, 1.0, 0.1]])

    def D(P, A, B, C):
        Q, _ = closest_point_on_triangles(P, A, B, C)
        return float(np.sum((P - Q) ** 2))

    h = 1e-6
    for P in ([[0.3, 0.3, 0.7]], [[0.5, -0.6, 0.2]], [[-0.5, -0.4, 0.3]]):  # face, edge, vertex
        P = np.array(P)
        Q, w = closest_point_on_triangles(P, A, B, C)
        g = 2 * (P - Q)[0]
        grads = [g, -w[0, 0] * g, -w[0, 1] * g, -w[0, 2] * g]
        args = [P, A, B, C]
        for which, analytic in enumerate(grads):
            fd = np.zeros(3)
            for i in range(3):
                e = np.zeros((1, 3))
                e[0, i] = h
                plus = [a + e if j == which else a for j, a in enumerate(args)]
                minus = [a - e if j == which else a for j, a in enumerate(args)]
                fd[i] = (D(*plus) - D(*minus)) / (2 * h)
            np.testing.assert_allclose(fd, analytic, atol=1e-7)


@pytest.mark.parametrize("mesh,spread", [(ico_sphere(3), 0.5), (ico_sphere(3), 1.5),
                                         (torus(1.0, 0.3, 24, 12), 1.0)])
def test_point_to_mesh_distance_matches_brute_force(mesh, spread):
    """Distances and closest points agree with a brute-force search over every face."""
    rng = np.random.default_rng(21)
    P = rng.normal(size=(800, 3)) * spread
    res = PointToMeshDistance(mesh).query(P)
    best, best_q = brute_closest(P, mesh.verts, mesh.faces)
    np.testing.assert_allclose(res.distances, best, rtol=0, atol=1e-9)
    near_unique = np.abs(res.distances - best) < 1e-12
    np.testing.assert_allclose(res.points, best_q, atol=1e-6)
    assert near_unique.mean() > 0.99
    # the result is self-consistent: bary on face_ids reproduce points, distances are |P - Q|
    tri = mesh.verts[mesh.faces[res.face_ids]]
    np.testing.assert_allclose(np.einsum("ki,kij->kj", res.bary, tri), res.points, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(P - res.points, axis=1), res.distances, atol=1e-15)
    assert res.face_ids.dtype == np.int64 and res.bary.dtype == np.float64


def test_one_ring_check_never_worse_than_open3d_face():
    """Without the one-ring check a float32 face choice can only over-estimate the distance."""
    mesh = ico_sphere(3)
    P = np.random.default_rng(22).normal(size=(1500, 3)) * 1.5
    best, _ = brute_closest(P, mesh.verts, mesh.faces)
    plain = PointToMeshDistance(mesh, one_ring=False).distance(P)
    checked = PointToMeshDistance(mesh, one_ring=True).distance(P)
    assert np.all(plain >= best - 1e-12) and np.all(checked <= plain + 1e-15)
    np.testing.assert_allclose(checked, best, atol=1e-12)


def test_point_to_mesh_distance_far_from_origin():
    """A mesh far from the origin and tiny (the float32 worst case) is still exact in float64."""
    mesh = ico_sphere(2).scale_verts(1e-3).offset_verts([1e4, -2e4, 3e3])
    rng = np.random.default_rng(23)
    P = mesh.verts.mean(axis=0) + rng.normal(size=(500, 3)) * 2e-3
    res = PointToMeshDistance(mesh).query(P)
    best, _ = brute_closest(P, mesh.verts, mesh.faces)
    np.testing.assert_allclose(res.distances, best, rtol=1e-9, atol=0)


def test_signed_distance_sphere():
    """Signed distance is negative inside and positive outside a sphere, with |sd| = distance."""
    s = ico_sphere(4)
    rng = np.random.default_rng(24)
    dirs = rng.normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radii = np.concatenate([rng.uniform(0.05, 0.98, 1000), rng.uniform(1.02, 3.0, 1000)])
    P = dirs * radii[:, None]
    pm = PointToMeshDistance(s)
    sd = pm.signed_distance(P)
    np.testing.assert_array_equal(sd < 0, radii < 1)
    np.testing.assert_allclose(np.abs(sd), pm.distance(P), rtol=0, atol=0)
    np.testing.assert_allclose(pm.signed_distance(P, nsamples=3), sd)
    # away from the polygon approximation the value is 1 - r to within the sphere sagitta
    np.testing.assert_allclose(sd, radii - 1, atol=2e-3)
    assert pm.signed_distance(np.zeros((0, 3))).shape == (0,)


def test_point_to_mesh_update_verts_and_empty_query():
    """update_verts moves the surface; an empty query gives empty arrays."""
    p = plane(size=2.0, n=2)
    pm = PointToMeshDistance(p)
    P = np.array([[0.1, 0.2, 1.0], [-0.3, 0.4, -2.0]])
    np.testing.assert_allclose(pm.distance(P), [1.0, 2.0], rtol=1e-15)
    assert pm.update_verts(p.verts + [0, 0, 0.5]) is pm
    np.testing.assert_allclose(pm.distance(P), [0.5, 2.5], rtol=1e-15)
    assert pm.mesh.verts[0, 2] == 0.5 and pm.n_faces == 8
    res = pm.query(np.zeros((0, 3)))
    assert isinstance(res, ClosestPoints)
    assert res.distances.shape == (0,) and res.points.shape == (0, 3)
    assert res.face_ids.shape == (0,) and res.face_ids.dtype == np.int64
    assert res.bary.shape == (0, 3)


def test_closest_validation():
    with pytest.raises(TypeError, match="mesh"):
        PointToMeshDistance(np.eye(3))
    with pytest.raises(ValueError, match="at least one face"):
        PointToMeshDistance(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
    with pytest.raises(ValueError, match="n_threads"):
        PointToMeshDistance(ico_sphere(1), n_threads=-1)
    pm = PointToMeshDistance(ico_sphere(1))
    with pytest.raises(ValueError, match="points"):
        pm.query(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="points"):
        pm.query([[np.inf, 0, 0]])
    with pytest.raises(ValueError, match="nsamples"):
        pm.signed_distance(np.zeros((1, 3)), nsamples=2)
    with pytest.raises(ValueError, match="watertight"):
        PointToMeshDistance(plane()).signed_distance(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="verts"):
        pm.update_verts(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="A"):
        closest_point_on_triangles(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros((2, 3)),
                                   np.zeros((2, 3)))
    with pytest.raises(ValueError, match="P"):
        closest_point_on_triangles(np.zeros((2, 4)), np.zeros((2, 3)), np.zeros((2, 3)),
                                   np.zeros((2, 3)))


def test_embree_scene_is_the_shared_wrapper():
    """EmbreeScene maps the used vertices into [-1, 1]^3, skips meshes without faces, and its
    float32 hits agree with RayCaster's; the mesh rasterizer casts against the same class."""
    from geofit.raycast import EmbreeScene
    from geofit.render import MeshRasterizer

    m = ico_sphere(1)
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    sc = EmbreeScene([empty, (2.0 * m.verts + 5.0, m.faces)])
    np.testing.assert_allclose(sc.center, 5.0, atol=1e-12)
    assert sc.scale == pytest.approx(2.0, rel=1e-12)
    assert sc.geom_to_mesh.tolist() == [1]
    o = np.array([[0.1, 0.2, 3.0]], np.float32)  # the normalised frame is m's own frame here
    geom, prim, u, v, t = sc.intersect(o, np.array([[0.0, 0.0, -1.0]], np.float32))
    hits = RayCaster(m).cast([[0.1, 0.2, 3.0]], [[0.0, 0.0, -1.0]])
    assert geom[0] == 0 and prim[0] == hits.face_id[0]
    assert float(t[0]) == pytest.approx(hits.t[0], abs=1e-5)
    assert sc.occluded(o, np.array([[0.0, 0.0, -1.0]], np.float32),
                       np.array([1.5], np.float32)).tolist() == [False]
    rast = MeshRasterizer()
    assert isinstance(rast._scene(m), EmbreeScene)
    with pytest.raises(ValueError, match="meshes"):
        EmbreeScene([empty])


def test_unit_box_maps_the_used_points_into_the_unit_cube():
    """Both float32 scenes (Embree's, Open3D's) normalise with one box: the longest side spans
    [-1, 1] and a single point gets scale 1."""
    from geofit.raycast.embree import unit_box

    P = np.array([[1.0, 2.0, 3.0], [5.0, 3.0, 4.0], [2.0, 2.5, 3.5]])
    c, s = unit_box(P)
    q = (P - c) / s
    assert np.isclose(s, 2.0) and np.allclose(q.min(0)[0], -1.0) and np.allclose(q.max(0)[0], 1.0)
    assert np.all(np.abs(q) <= 1.0)
    c1, s1 = unit_box(P[:1])
    assert s1 == 1.0 and np.array_equal(c1, P[0])
