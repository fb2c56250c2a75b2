"""The witness search for far queries: exact on every chamfer scene, ties included,
deterministic."""
import numpy as np
import pytest
from numpy.testing import assert_array_equal
from scipy.spatial import cKDTree

import geofit
from geofit import _threads
from geofit.loss import _chamfer_search as cs
from geofit.loss import chamfer as ch
from geofit.loss import chamfer_distance
from geofit.ops import sample_points_from_meshes


def _brute(p, q):
    """Squared distance from each p to its nearest q, by a full distance matrix."""
    return ((p[:, None, :] - q[None, :, :]) ** 2).sum(-1).min(axis=1)


def _scenes(n):
    """The benchmark's three scenes, small: a torus inside a sphere stands in for the dolphin."""
    torus = sample_points_from_meshes(geofit.torus(0.5, 0.2, 24, 12), 2 * n, seed=0)
    sphere = sample_points_from_meshes(geofit.ico_sphere(3), n, seed=1)
    y = torus[:n]
    return {"overlap": (torus[n:], y), "tutorial": (sphere, y), "apart": (sphere + [3.0, 0, 0], y)}


def _sorted(points):
    codes = cs.morton_codes(points)
    order = np.argsort(codes, kind="stable")
    return np.ascontiguousarray(points[order]), codes[order]


def _small_blocks(monkeypatch):
    """Small blocks, chunks and batches, so that a few thousand points exercise every path."""
    monkeypatch.setattr(cs, "_K_TOP", 64)
    monkeypatch.setattr(cs, "_K_MIN", 4)
    monkeypatch.setattr(cs, "_CHUNK", 1000)
    monkeypatch.setattr(cs, "_COMBOS", 5000)


def _search(tree_points, codes, q, calls=None):
    tree = cKDTree(tree_points)

    def kd(rows):
        if calls is not None:
            calls.append(len(rows))
        return tree.query(q[rows])[1]

    return cs.WitnessSearch(tree_points, codes).nearest(q, kd)


@pytest.mark.parametrize("scene", ["overlap", "tutorial", "apart"])
def test_witness_search_is_exact_on_every_scene(monkeypatch, scene):
    """Both directions of each scene: every query's distance equals the brute-force minimum."""
    _small_blocks(monkeypatch)
    x, y = _scenes(1500)[scene]
    for p, q in ((x, y), (y, x)):
        tp, codes = _sorted(q)
        qs, _ = _sorted(p)
        calls = []
        idx = _search(tp, codes, qs, calls)
        assert idx.min() >= 0
        assert_array_equal(((qs - tp[idx]) ** 2).sum(1), _brute(qs, tp))
        if scene == "apart":  # far: (nearly) every block is searched with witnesses
            assert sum(calls) < 0.05 * len(qs)
        if scene == "overlap":  # near: (nearly) every block goes back to the KD-tree
            assert sum(calls) > 0.9 * len(qs)


def test_heavy_blocks_go_to_the_kd_tree(monkeypatch):
    """Blocks with more candidates than _HEAVY are searched by the KD-tree: still exact."""
    _small_blocks(monkeypatch)
    monkeypatch.setattr(cs, "_HEAVY", 4)
    x, y = _scenes(1500)["tutorial"]
    tp, codes = _sorted(x)
    qs, _ = _sorted(y)
    calls = []
    idx = _search(tp, codes, qs, calls)
    assert 0 < sum(calls) < len(qs)
    assert_array_equal(((qs - tp[idx]) ** 2).sum(1), _brute(qs, tp))


def test_ties_are_exact_and_deterministic(monkeypatch):
    """A lattice seen from a parallel plane far away: every query has 2 or 4 equidistant nearest
    points; the distances are the brute-force ones and the chosen points do not depend on the
    thread count."""
    _small_blocks(monkeypatch)
    g = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0), [0.0], indexing="ij"),
                 -1).reshape(-1, 3)
    tp, codes = _sorted(g * 0.125)
    s = np.stack(np.meshgrid(np.arange(30.0), np.arange(30.0), [0.0], indexing="ij"),
                 -1).reshape(-1, 3)
    q = (s + [5.5, 5.5, 0.0]) * 0.125 + [0.0, 0.0, 4.0]  # midway between lattice points
    q[::3, 0] -= 0.0625  # a third of them midway on one axis only: 2 ties
    qs, _ = _sorted(q)
    idx = _search(tp, codes, qs)
    d = ((qs - tp[idx]) ** 2).sum(1)
    assert_array_equal(d, _brute(qs, tp))
    ties = (((qs[:, None] - tp[None]) ** 2).sum(-1) == d[:, None]).sum(1)
    assert ties.min() >= 2 and ties.max() == 4
    for threads in (1, 2):
        _threads.set_num_threads(threads)
        try:
            assert_array_equal(_search(tp, codes, qs), idx)
        finally:
            _threads.set_num_threads(None)


def test_chamfer_auto_takes_the_witness_search_for_far_clouds(monkeypatch):
    """'auto' samples the queries: far clouds take the witness search, overlapping ones do not;
    the loss and the gradients are those of the plain scipy search."""
    _small_blocks(monkeypatch)
    for name in ("_MORTON_FROM", "_WITNESS_FROM"):
        monkeypatch.setattr(ch, name, 100)
    monkeypatch.setattr(ch, "_SAMPLE", 64)
    scenes = _scenes(1200)
    for scene, far in (("apart", True), ("tutorial", True), ("overlap", False)):
        x, y = scenes[scene]
        index = ch._NearestIndex(y, "auto")
        idx = index.nearest(x, 2)
        assert (index._witness is not None) == far, scene
        assert_array_equal(((x - y[idx]) ** 2).sum(1), _brute(x, y))
        a = chamfer_distance(x, y)
        b = chamfer_distance(x, y, backend="scipy")
        assert a.loss == b.loss
        assert_array_equal(a.grad_x, b.grad_x)
        assert_array_equal(a.grad_y, b.grad_y)


def test_leaf_level_holds_few_points():
    """The finest octree level has at most _LEAF points per cell on average, its parent more."""
    pts = np.random.default_rng(1).random((5000, 3))
    _, codes = _sorted(pts)
    lv = cs.leaf_level(codes)

    def cells(level):
        return len(np.unique(codes >> np.uint64(3 * (cs.MORTON_BITS - level))))

    assert len(pts) <= cs._LEAF * cells(lv)
    assert len(pts) > cs._LEAF * cells(lv - 1)


def test_far_share_tells_far_queries_without_a_tree():
    """Queries on the cloud's surface are near, a copy moved 3 units away is far, and queries
    just outside the cloud's cube (within one cell) count as near."""
    x, y = _scenes(3000)["apart"]
    tp, codes = _sorted(y)
    frame = cs.morton_frame(y)
    level = cs.leaf_level(codes) - 2
    assert cs.far_share(codes, frame, y[::7], level) == 0.0
    assert cs.far_share(codes, frame, x, level) == 1.0
    edge = y[np.argmax(y[:, 0])] + [1e-3, 0.0, 0.0]  # just past the cube's face
    assert cs.far_share(codes, frame, edge[None], level) == 0.0
    assert cs.far_share(codes, frame, np.zeros((0, 3)), level) == 0.0


def test_queries_on_the_cloud_are_exact_with_single_query_blocks(monkeypatch):
    """Blocks of one query (no extent) a hair off the points of a tilted flat grid: the oriented
    boxes' rounding must not prune the nearest point (every block is searched by witnesses)."""
    monkeypatch.setattr(cs, "_K_TOP", 1)
    monkeypatch.setattr(cs, "_K_MIN", 1)
    g = np.stack(np.meshgrid(np.linspace(0, 1, 60), np.linspace(0, 1, 60), [0.0],
                             indexing="ij"), -1).reshape(-1, 3)
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[c, 0, s], [0, 1, 0],
                                                                     [-s, 0, c]])
    tp, codes = _sorted(g @ rot.T + 10.0)
    rng = np.random.default_rng(3)
    q = tp[rng.choice(len(tp), 300, replace=False)] + rng.normal(scale=1e-13, size=(300, 3))
    qs, _ = _sorted(q)
    calls = []
    idx = _search(tp, codes, qs, calls)
    assert sum(calls) < len(qs)
    assert_array_equal(((qs - tp[idx]) ** 2).sum(1), _brute(qs, tp))
