"""Chamfer distance: PyTorch3D parity in every variant, finite differences, closed forms."""
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geofit.loss import ChamferResult, ChamferTarget, chamfer_distance

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def ref():
    with np.load(DATA / "mesh_ops.npz") as d:  # stored compactly: widen back
        return {k: d[k].astype(np.int64 if d[k].dtype.kind == "i" else np.float64)
                for k in d.files if k.startswith("chamfer_")}


VARIANTS = {
    "default": {},
    "sum": {"point_reduction": "sum"},
    "single": {"single_directional": True},
    "norm1": {"norm": 1},
    "max": {"point_reduction": "max"},
    "normals_abs": {"normals": True, "abs_cosine": True},
    "normals_signed": {"normals": True, "abs_cosine": False},
}
BATCH_VARIANTS = {
    "batch": {},
    "batch_nored": {"batch_reduction": None},
    "batch_sum": {"point_reduction": "sum", "batch_reduction": "sum"},
}


def _rel(a, b):
    """Largest absolute error normalised by the largest reference entry."""
    b = np.asarray(b)
    return np.abs(np.asarray(a) - b).max() / np.abs(b).max()


def _kwargs(ref, opts):
    kw = {k: v for k, v in opts.items() if k != "normals"}
    if opts.get("normals"):
        kw["x_normals"] = ref["chamfer_x_normals"]
        kw["y_normals"] = ref["chamfer_y_normals"]
    return kw


@pytest.mark.parametrize("name", list(VARIANTS))
def test_matches_pytorch3d(ref, name):
    """Loss, gradients (and the normal term with its normal gradients) agree to float32 accuracy."""
    r = chamfer_distance(ref["chamfer_x"], ref["chamfer_y"], **_kwargs(ref, VARIANTS[name]))
    assert isinstance(r, ChamferResult)
    assert_allclose(r.loss, ref[f"chamfer_{name}_loss"], rtol=1e-6)
    assert _rel(r.grad_x, ref[f"chamfer_{name}_grad_x"]) < 1e-5
    assert _rel(r.grad_y, ref[f"chamfer_{name}_grad_y"]) < 1e-5
    assert r.grad_x.shape == (1, 1000, 3) and r.grad_y.shape == (1, 800, 3)
    if VARIANTS[name].get("normals"):
        assert_allclose(r.loss_normals, ref[f"chamfer_{name}_loss_normals"], rtol=1e-6)
        assert _rel(r.grad_x_normals, ref[f"chamfer_{name}_grad_x_normals"]) < 1e-5
        assert _rel(r.grad_y_normals, ref[f"chamfer_{name}_grad_y_normals"]) < 1e-5
    else:
        assert r.loss_normals is None and r.grad_x_normals is None and r.grad_y_normals is None


@pytest.mark.parametrize("name", list(BATCH_VARIANTS))
def test_batch_matches_pytorch3d(ref, name):
    """Padded batches with lengths: every reduction agrees; padding gets zero gradient."""
    lx, ly = ref["chamfer_batch_x_lengths"], ref["chamfer_batch_y_lengths"]
    r = chamfer_distance(ref["chamfer_batch_x"], ref["chamfer_batch_y"], x_lengths=lx,
                         y_lengths=ly, **BATCH_VARIANTS[name])
    assert_allclose(r.loss, ref[f"chamfer_{name}_loss"], rtol=1e-6)
    assert np.shape(r.loss) == np.shape(ref[f"chamfer_{name}_loss"])
    assert _rel(r.grad_x, ref[f"chamfer_{name}_grad_x"]) < 1e-5
    assert _rel(r.grad_y, ref[f"chamfer_{name}_grad_y"]) < 1e-5
    for b in range(2):
        assert not r.grad_x[b, lx[b]:].any() and not r.grad_y[b, ly[b]:].any()


@pytest.mark.parametrize("name", list(VARIANTS))
def test_chamfer_target_matches_chamfer_distance(ref, name):
    """ChamferTarget (prebuilt tree over y) gives the same values and gradients."""
    opts = VARIANTS[name]
    x, y = ref["chamfer_x"][0], ref["chamfer_y"][0]
    kw = {k: v for k, v in opts.items() if k != "normals"}
    full = chamfer_distance(x, y, **_kwargs({"chamfer_x_normals": ref["chamfer_x_normals"][0],
                                              "chamfer_y_normals": ref["chamfer_y_normals"][0]},
                                             opts))
    if opts.get("normals"):
        target = ChamferTarget(y, y_normals=ref["chamfer_y_normals"][0])
        r = target.chamfer(x, x_normals=ref["chamfer_x_normals"][0], **kw)
        assert_allclose(r.loss_normals, full.loss_normals, rtol=1e-14)
        assert_allclose(r.grad_x_normals, full.grad_x_normals, rtol=1e-14, atol=1e-18)
        assert_allclose(r.grad_y_normals, full.grad_y_normals, rtol=1e-14, atol=1e-18)
    else:
        target = ChamferTarget(y)
        r = target.chamfer(x, **kw)
        value, grad = target.loss(x, **kw)
        assert_allclose(value, full.loss, rtol=1e-14)
        assert_allclose(grad, full.grad_x, rtol=1e-14, atol=1e-18)
    assert_allclose(r.loss, full.loss, rtol=1e-14)
    assert_allclose(r.grad_x, full.grad_x, rtol=1e-14, atol=1e-18)
    assert_allclose(r.grad_y, full.grad_y, rtol=1e-14, atol=1e-18)
    assert_allclose(r.loss, ref[f"chamfer_{name}_loss"], rtol=1e-6)


# --------------------------------------------------------------------------- finite differences
def _tiny(seed=0, n=7, m=5, batch=None):
    """Small random clouds whose nearest neighbours are far from ties (margin checked)."""
    rng = np.random.default_rng(seed)
    shape_x = (n, 3) if batch is None else (batch, n, 3)
    shape_y = (m, 3) if batch is None else (batch, m, 3)
    x = rng.uniform(-1, 1, shape_x)
    y = rng.uniform(-1, 1, shape_y)
    for a, b in ((x, y), (y, x)):
        A, B = a.reshape(-1, a.shape[-2], 3), b.reshape(-1, b.shape[-2], 3)
        for i in range(len(A)):  # batch members
            for norm in (1, 2):
                d = np.linalg.norm(A[i][:, None] - B[i][None], ord=norm, axis=2)
                d.sort(axis=1)
                assert np.all(d[:, 1] - d[:, 0] > 1e-3)  # no near-ties: the FD steps keep the nn
    return x, y


def _fd(f, a, h=1e-6):
    g = np.zeros_like(a)
    for idx in np.ndindex(*a.shape):  # loop over the coordinates of a tiny input
        ap = a.copy()
        am = a.copy()
        ap[idx] += h
        am[idx] -= h
        g[idx] = (np.sum(f(ap)) - np.sum(f(am))) / (2 * h)
    return g


FD_OPTIONS = [
    {},
    {"point_reduction": "sum"},
    {"single_directional": True},
    {"norm": 1},
    {"norm": 1, "point_reduction": "sum", "single_directional": True},
    {"point_reduction": "max"},
    {"point_reduction": "max", "single_directional": True},
    {"point_reduction": "max", "norm": 1},
]


@pytest.mark.parametrize("opts", FD_OPTIONS, ids=lambda o: "-".join(f"{k}={v}" for k, v in o.items())
                         or "default")
def test_finite_differences_both_arguments(opts):
    """Central differences w.r.t. x and y equal grad_x and grad_y in every reduction / norm."""
    x, y = _tiny(seed=1)
    r = chamfer_distance(x, y, **opts)
    fx = _fd(lambda a: chamfer_distance(a, y, **opts).loss, x)
    fy = _fd(lambda b: chamfer_distance(x, b, **opts).loss, y)
    assert_allclose(r.grad_x, fx, rtol=1e-6, atol=1e-9)
    assert_allclose(r.grad_y, fy, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("abs_cosine", [True, False])
def test_finite_differences_normals(abs_cosine):
    """The normal term's gradients w.r.t. both normal sets (non-unit normals too)."""
    x, y = _tiny(seed=2)
    rng = np.random.default_rng(3)
    xn = rng.normal(size=x.shape)
    yn = rng.normal(size=y.shape) * rng.uniform(0.5, 2.0, (len(y), 1))
    kw = {"abs_cosine": abs_cosine}
    r = chamfer_distance(x, y, x_normals=xn, y_normals=yn, **kw)
    fxn = _fd(lambda a: chamfer_distance(x, y, x_normals=a, y_normals=yn, **kw).loss_normals, xn)
    fyn = _fd(lambda b: chamfer_distance(x, y, x_normals=xn, y_normals=b, **kw).loss_normals, yn)
    assert_allclose(r.grad_x_normals, fxn, rtol=1e-6, atol=1e-9)
    assert_allclose(r.grad_y_normals, fyn, rtol=1e-6, atol=1e-9)
    # the distance term is unchanged by the presence of normals
    plain = chamfer_distance(x, y)
    assert r.loss == plain.loss
    assert_array_equal(r.grad_x, plain.grad_x)


@pytest.mark.parametrize("opts", [{}, {"batch_reduction": None},
                                  {"batch_reduction": "sum", "point_reduction": "sum"},
                                  {"weights": np.array([0.3, 1.7])},
                                  {"weights": np.array([0.3, 1.7]), "point_reduction": "max"}],
                         ids=["mean", "none", "sum", "weights", "weights-max"])
def test_finite_differences_padded_batch(opts):
    """Batch with lengths: FD gradients match; padding has zero gradient and no influence."""
    x, y = _tiny(seed=4, n=6, m=5, batch=2)
    lx, ly = np.array([6, 4]), np.array([3, 5])
    kw = dict(x_lengths=lx, y_lengths=ly, **opts)
    r = chamfer_distance(x, y, **kw)
    fx = _fd(lambda a: chamfer_distance(a, y, **kw).loss, x)
    fy = _fd(lambda b: chamfer_distance(x, b, **kw).loss, y)
    assert_allclose(r.grad_x, fx, rtol=1e-6, atol=1e-9)
    assert_allclose(r.grad_y, fy, rtol=1e-6, atol=1e-9)
    x2 = x.copy()
    x2[1, 4:] = 100.0  # padding moves: nothing changes
    r2 = chamfer_distance(x2, y, **kw)
    assert_array_equal(r2.loss, r.loss)
    assert_array_equal(r2.grad_x, r.grad_x)


def test_batch_equals_members():
    """Batch reductions combine the single-cloud results exactly as documented."""
    x, y = _tiny(seed=5, n=6, m=5, batch=2)
    lx, ly = np.array([6, 4]), np.array([3, 5])
    single = [chamfer_distance(x[b, :lx[b]], y[b, :ly[b]]) for b in range(2)]
    per = np.array([s.loss for s in single])
    none = chamfer_distance(x, y, x_lengths=lx, y_lengths=ly, batch_reduction=None)
    assert_allclose(none.loss, per, rtol=1e-15)
    mean = chamfer_distance(x, y, x_lengths=lx, y_lengths=ly)
    assert_allclose(mean.loss, per.mean(), rtol=1e-15)
    assert_allclose(mean.grad_x[1, :4], single[1].grad_x / 2, rtol=1e-15)
    w = np.array([0.25, 1.0])
    wm = chamfer_distance(x, y, x_lengths=lx, y_lengths=ly, weights=w)
    assert_allclose(wm.loss, (w * per).sum() / w.sum(), rtol=1e-14)
    ws = chamfer_distance(x, y, x_lengths=lx, y_lengths=ly, weights=w, batch_reduction="sum")
    assert_allclose(ws.loss, (w * per).sum(), rtol=1e-14)
    zero = chamfer_distance(x, y, weights=[0.0, 0.0])
    assert zero.loss == 0.0 and not zero.grad_x.any() and not zero.grad_y.any()


# --------------------------------------------------------------------------- closed forms
def test_one_point_each_is_18():
    """(0, 0) against (3, 0): 9 + 9 = 18 (the directions are summed); L1: 6; max/single: 9."""
    x, y = np.array([[0.0, 0, 0]]), np.array([[3.0, 0, 0]])
    r = chamfer_distance(x, y)
    assert r.loss == 18.0
    assert_array_equal(r.grad_x, [[-12.0, 0, 0]])
    assert_array_equal(r.grad_y, [[12.0, 0, 0]])
    assert chamfer_distance(x, y, norm=1).loss == 6.0
    assert chamfer_distance(x, y, point_reduction="max").loss == 9.0
    assert chamfer_distance(x, y, single_directional=True).loss == 9.0
    tie = chamfer_distance(x, y, point_reduction="max")
    assert_array_equal(tie.grad_x, [[-6.0, 0, 0]])  # tie of the two maxima: split evenly
    assert_array_equal(tie.grad_y, [[6.0, 0, 0]])


def test_identical_clouds_and_hausdorff():
    """A cloud against itself: 0 with zero gradients; 'max' is the squared Hausdorff distance."""
    x = np.random.default_rng(6).normal(size=(50, 3))
    r = chamfer_distance(x, x)
    assert r.loss == 0.0 and not r.grad_x.any() and not r.grad_y.any()
    y = np.concatenate([x, [[10.0, 0, 0]]])
    far = np.min(np.sum((x - [10.0, 0, 0]) ** 2, axis=1))
    assert_allclose(chamfer_distance(x, y, point_reduction="max").loss, far, rtol=1e-15)
    assert chamfer_distance(x, y, point_reduction="max", single_directional=True).loss == 0.0


def test_normal_term_closed_forms():
    """Parallel normals: 0; perpendicular: 1 per direction; opposite: 0 with abs, 2 signed."""
    x, y = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]])
    n = np.array([[0.0, 0, 1]])
    assert chamfer_distance(x, y, x_normals=n, y_normals=2 * n).loss_normals == 0.0
    assert_allclose(chamfer_distance(x, y, x_normals=n, y_normals=[[1.0, 0, 0]]).loss_normals, 2.0)
    assert chamfer_distance(x, y, x_normals=n, y_normals=-n).loss_normals == 0.0
    assert_allclose(chamfer_distance(x, y, x_normals=n, y_normals=-n,
                                     abs_cosine=False).loss_normals, 4.0)


def test_empty_other_cloud_contributes_zero():
    """A member whose other cloud has length 0 contributes 0 in that direction."""
    x = np.random.default_rng(7).normal(size=(1, 4, 3))
    y = np.random.default_rng(8).normal(size=(1, 3, 3))
    r = chamfer_distance(x, y, y_lengths=[0])
    assert r.loss == 0.0 and not r.grad_x.any()


def test_chamfer_target_reuses_its_tree():
    """The target's KD-tree is built once; repeated calls with moving x stay consistent."""
    rng = np.random.default_rng(9)
    y = rng.normal(size=(300, 3))
    t = ChamferTarget(y)
    index = t._index
    for k in range(3):
        x = rng.normal(size=(200, 3)) + 0.1 * k
        v, g = t.loss(x)
        if k == 0:
            tree = index._pykdtree  # "auto" on small clouds
        r = chamfer_distance(x, y)
        assert_allclose(v, r.loss, rtol=1e-14)
        assert_allclose(g, r.grad_x, rtol=1e-14, atol=1e-18)
    assert t._index is index and index._pykdtree is tree and tree is not None and len(t) == 300
    assert "300" in repr(t)


# --------------------------------------------------------------------------- validation
def test_validation_errors():
    x = np.zeros((4, 3))
    y = np.ones((5, 3))
    cases = [
        ({"batch_reduction": "avg"}, "batch_reduction"),
        ({"point_reduction": "median"}, "point_reduction"),
        ({"point_reduction": None}, "point_reduction"),
        ({"norm": 3}, "norm"),
        ({"norm": "l2"}, "norm"),
        ({"norm": True}, "norm"),
        ({"point_reduction": "max", "x_normals": x, "y_normals": y}, "max"),
        ({"x_normals": x}, "both"),
        ({"y_normals": y}, "both"),
        ({"x_normals": np.zeros((3, 3)), "y_normals": y}, "x_normals"),
        ({"x_lengths": [2, 3]}, "x_lengths"),
        ({"x_lengths": [5]}, "x_lengths"),
        ({"y_lengths": [-1]}, "y_lengths"),
        ({"y_lengths": [1.5]}, "y_lengths"),
        ({"weights": [-1.0]}, "weights"),
        ({"weights": [1.0, 2.0]}, "weights"),
    ]
    for kw, msg in cases:
        with pytest.raises(ValueError, match=msg):
            chamfer_distance(x, y, **kw)
    with pytest.raises(ValueError, match="x"):
        chamfer_distance(np.zeros((4, 2)), y)
    with pytest.raises(ValueError, match="x"):
        chamfer_distance(np.zeros((1, 2, 4, 3)), y)
    with pytest.raises(ValueError, match="x"):
        chamfer_distance([[0.0, 0, 0], [1.0, 2]], y)  # ragged
    bad = x.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="x"):
        chamfer_distance(bad, y)
    with pytest.raises(ValueError, match="y"):
        chamfer_distance(np.zeros((2, 4, 3)), np.zeros((3, 5, 3)))
    with pytest.raises(ValueError, match="y"):
        ChamferTarget(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="y_normals"):
        ChamferTarget(y, y_normals=np.zeros((4, 3)))
    t = ChamferTarget(y)
    with pytest.raises(ValueError, match="x_normals"):
        t.chamfer(x, x_normals=x)
    with pytest.raises(ValueError, match="point_reduction"):
        t.loss(x, point_reduction="mean_of_means")
    with pytest.raises(ValueError, match="norm"):
        t.loss(x, norm=0)
    with pytest.raises(ValueError, match="x"):
        t.loss(np.zeros((4, 2)))


# --------------------------------------------------------------------------- point to surface
def _outside_points(mesh, n, seed, lo=0.2, hi=0.6):
    """Points outside a convex mesh along random directions (no medial-axis ties outside)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (1.0 + rng.uniform(lo, hi, (n, 1)))


def test_point_to_surface_closed_forms():
    """Above a unit box face: (z - 0.5)^2, gradient 2 (p - c) / n; near a corner: the corner."""
    from geofit import box
    from geofit.loss import PointToSurface

    t = PointToSurface(box())
    P = np.array([[0.1, -0.2, 2.0], [1.5, 1.5, 1.5]])
    v, g = t.loss(P)
    d2 = np.array([1.5**2, 3 * 1.0**2])
    assert_allclose(v, d2.mean(), rtol=1e-14)
    assert_allclose(g, 2 * (P - [[0.1, -0.2, 0.5], [0.5, 0.5, 0.5]]) / 2, rtol=1e-14, atol=1e-15)
    vs, gs = t.loss(P, reduction="sum")
    assert_allclose(vs, d2.sum(), rtol=1e-14)
    assert_allclose(gs, 2 * g, rtol=1e-14)
    v0, g0 = t.loss(np.zeros((0, 3)))
    assert v0 == 0.0 and g0.shape == (0, 3)
    assert t.query(P).face_ids.shape == (2,) and "PointToSurface" in repr(t)


def test_point_to_surface_finite_differences():
    """Central differences of the exact distance equal 2 (p - c) / n (points off the medial axis)."""
    from geofit import ico_sphere
    from geofit.loss import PointToSurface

    m = ico_sphere(1)
    t = PointToSurface(m)
    P = _outside_points(m, 12, seed=10)
    _v, g = t.loss(P)
    fd = _fd(lambda a: t.loss(a)[0], P)
    assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_point_to_surface_has_no_sampling_noise():
    """Samples of the target are at distance ~0 from it, unlike chamfer against other samples."""
    from geofit import ico_sphere
    from geofit.loss import PointToSurface
    from geofit.ops import sample_points_from_meshes

    m = ico_sphere(2)
    t = PointToSurface(m)
    a = sample_points_from_meshes(m, 2000, seed=0)
    b = sample_points_from_meshes(m, 2000, seed=1)
    v, g = t.loss(a)
    assert v < 1e-24 and np.abs(g).max() < 1e-11
    assert chamfer_distance(a, b).loss > 1e-4


def test_point_to_surface_chain_rule_through_sampling():
    """d/dV loss(B V) = B^T grad: finite differences over the vertices of a source mesh."""
    from geofit import ico_sphere
    from geofit.loss import PointToSurface
    from geofit.ops import sample_points_with_jacobian

    target = PointToSurface(ico_sphere(2))
    src = ico_sphere(0).scale_verts(1.4)
    s = sample_points_with_jacobian(src, 60, seed=3)
    _v, g = target.loss(s.B @ src.verts)
    gV = s.B.T @ g
    fd = _fd(lambda V: target.loss(s.B @ V)[0], src.verts.copy())
    assert_allclose(gV, fd, rtol=1e-6, atol=1e-9)


def test_point_to_surface_symmetric_loss():
    """symmetric_loss = loss + one-sided chamfer from target samples; FD-exact gradient."""
    from geofit import ico_sphere
    from geofit.loss import PointToSurface

    m = ico_sphere(1)
    t = PointToSurface(m)
    P = _outside_points(m, 10, seed=11)
    T = _outside_points(m, 8, seed=12, lo=0.0, hi=0.01)
    v, g = t.symmetric_loss(P, T)
    fwd = t.loss(P)
    rev = chamfer_distance(T, P, single_directional=True)
    assert_allclose(v, fwd[0] + rev.loss, rtol=1e-14)
    assert_allclose(g, fwd[1] + rev.grad_y, rtol=1e-13, atol=1e-16)
    fd = _fd(lambda a: t.symmetric_loss(a, T)[0], P)
    assert_allclose(g, fd, rtol=1e-6, atol=1e-9)
    vs, _ = t.symmetric_loss(P, T, reduction="sum")
    assert_allclose(vs, t.loss(P, reduction="sum")[0]
                    + chamfer_distance(T, P, single_directional=True, point_reduction="sum").loss,
                    rtol=1e-14)
    assert t.symmetric_loss(P, np.zeros((0, 3)))[0] == fwd[0]


def test_point_to_surface_validation():
    from geofit import Mesh, ico_sphere
    from geofit.loss import PointToSurface

    with pytest.raises(TypeError, match="mesh"):
        PointToSurface(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="face"):
        PointToSurface(Mesh(np.zeros((3, 3)), np.zeros((0, 3), np.int64)))
    t = PointToSurface(ico_sphere(0))
    with pytest.raises(ValueError, match="reduction"):
        t.loss(np.zeros((2, 3)), reduction="max")
    with pytest.raises(ValueError, match="reduction"):
        t.symmetric_loss(np.zeros((2, 3)), np.zeros((2, 3)), reduction=None)
    with pytest.raises(ValueError, match="points"):
        t.loss(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="points"):
        t.loss(np.full((2, 3), np.nan))
    with pytest.raises(ValueError, match="points"):
        t.symmetric_loss(np.zeros((0, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="target_samples"):
        t.symmetric_loss(np.zeros((2, 3)), np.zeros((2, 4)))


def test_unpacks_like_pytorch3d():
    """``loss, loss_normals = chamfer_distance(x, y)`` as in PyTorch3D; gradients stay attributes."""
    x = [[0.0, 0, 0]]
    y = [[3.0, 0, 0]]
    loss, loss_normals = chamfer_distance(x, y)
    assert loss == 18.0 and loss_normals is None
    r = chamfer_distance(x, y)
    assert len(r) == 2 and r[0] == 18.0 and r[1] is None and tuple(r) == (18.0, None)
    assert_array_equal(r.grad_x, [[-12.0, 0, 0]])
    n = [[0.0, 0, 1]]
    loss, loss_normals = chamfer_distance(x, y, x_normals=n, y_normals=n)
    assert loss == 18.0 and loss_normals == 0.0
    target_loss, target_normals = ChamferTarget(y).chamfer(x)
    assert target_loss == 18.0 and target_normals is None


def test_docstring_examples_run():
    """The Examples sections of geofit.loss.chamfer run as doctests."""
    import doctest

    import geofit.loss.chamfer as mod

    result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def _brute_nearest_sqdist(p, q):
    """Reference: squared distance from each p to its nearest q, by a full distance matrix."""
    d = ((p[:, None, :] - q[None, :, :]) ** 2).sum(-1)
    return d.min(axis=1)


@pytest.mark.parametrize("backend", ["scipy", "open3d", "pykdtree", "auto"])
@pytest.mark.parametrize("offset", [0.0, 3.0])
def test_backends_find_the_exact_nearest_neighbours(backend, offset):
    """Each backend's neighbours have the brute-force distances, overlapping or far apart."""
    from geofit.loss.chamfer import _NearestIndex

    rng = np.random.default_rng(4)
    y = rng.normal(size=(700, 3))
    y /= np.linalg.norm(y, axis=1, keepdims=True)  # a sphere: far queries are hard for trees
    x = 0.3 * rng.normal(size=(500, 3)) + [offset, 0.0, 0.0]
    for p, q in ((x, y), (y, x)):
        idx = _NearestIndex(q, backend).nearest(p, 2)
        d = ((p - q[idx]) ** 2).sum(1)
        assert_array_equal(d, _brute_nearest_sqdist(p, q))
    r = chamfer_distance(x, y, backend=backend)
    want = _brute_nearest_sqdist(x, y).mean() + _brute_nearest_sqdist(y, x).mean()
    assert_allclose(r.loss, want, rtol=1e-14)


def test_backends_agree_on_values_and_gradients():
    """Open3D and scipy give the same loss and gradients; 'auto' samples large query sets on
    scipy's tree (and keeps it for queries near the cloud)."""
    from geofit.loss import chamfer as ch

    rng = np.random.default_rng(5)
    x = rng.normal(size=(ch._OPEN3D_FROM, 3))
    y = rng.normal(size=(ch._OPEN3D_FROM + 10, 3)) + [0.5, 0, 0]
    a = chamfer_distance(x, y, backend="scipy")
    b = chamfer_distance(x, y, backend="open3d")
    assert_allclose(a.loss, b.loss, rtol=1e-13)
    assert_allclose(a.grad_x, b.grad_x, rtol=0, atol=1e-15)
    assert_allclose(a.grad_y, b.grad_y, rtol=0, atol=1e-15)
    big = ch._NearestIndex(y, "auto")
    big.nearest(x, 2)  # overlapping: scipy's tree on a sample, then on all the queries
    assert big._scipy is not None and big._witness is None and big._open3d is None
    forced = ch._NearestIndex(y, "open3d")
    forced.nearest(x, 2)
    assert forced._open3d is not None and forced._scipy is None
    small = ch._NearestIndex(y[:100], "auto")
    small.nearest(x[:100], 2)  # small clouds: pykdtree
    assert small._pykdtree is not None and small._scipy is None and small._open3d is None
    l1 = ch._NearestIndex(y, "auto")
    l1.nearest(x, 1)  # L1: scipy only
    assert l1._scipy is not None and l1._open3d is None and l1._pykdtree is None
    l1 = ch._NearestIndex(y[:100], "auto")
    l1.nearest(x[:100], 1)
    assert l1._scipy is not None and l1._pykdtree is None


def test_backend_validation():
    """An unknown backend, or Open3D or pykdtree with the L1 norm, raises naming the backend."""
    x = np.zeros((2, 3))
    with pytest.raises(ValueError, match="backend"):
        chamfer_distance(x, x, backend="faiss")
    with pytest.raises(ValueError, match="backend: 'open3d' has no L1"):
        chamfer_distance(x, x, backend="open3d", norm=1)
    with pytest.raises(ValueError, match="backend: 'pykdtree' has no L1"):
        chamfer_distance(x, x, backend="pykdtree", norm=1)
    with pytest.raises(ValueError, match="backend"):
        ChamferTarget(x, backend="kd")
    with pytest.raises(ValueError, match="backend"):
        ChamferTarget(x, backend="open3d").loss(x, norm=1)


def test_morton_order_is_a_local_permutation():
    """The Z-order is a permutation; on an 8^3 grid its first 8 points are the corner 2^3 cube."""
    from geofit.loss.chamfer import morton_order

    g = np.stack(np.meshgrid(*[np.arange(8.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    shuffled = g[np.random.default_rng(0).permutation(len(g))]
    o = morton_order(shuffled)
    assert_array_equal(np.sort(o), np.arange(len(g)))
    first = shuffled[o[:8]]
    assert_array_equal(np.sort(first, axis=0).max(axis=0), [1.0, 1.0, 1.0])
    assert len(np.unique(first, axis=0)) == 8
    assert_array_equal(morton_order(np.zeros((5, 3))), np.arange(5))  # no extent: stable


@pytest.mark.parametrize("backend", ["scipy", "open3d"])
def test_z_ordered_search_is_exact(monkeypatch, backend):
    """Above _MORTON_FROM points the tree and the queries are sorted: answers stay exact."""
    from geofit.loss import chamfer as ch

    monkeypatch.setattr(ch, "_MORTON_FROM", 16)
    rng = np.random.default_rng(8)
    y = rng.normal(size=(600, 3))
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    x = 0.4 * rng.normal(size=(450, 3)) + [0.2, 3.0, 0.0]
    for p, q in ((x, y), (y, x), (x, x + 1e-3)):
        index = ch._NearestIndex(q, backend)
        assert index._order is not None
        idx = index.nearest(p, 2)
        assert_array_equal(((p - q[idx]) ** 2).sum(1), _brute_nearest_sqdist(p, q))
    r = chamfer_distance(x, y, backend=backend)
    monkeypatch.setattr(ch, "_MORTON_FROM", 10 ** 9)
    plain = chamfer_distance(x, y, backend=backend)
    assert r.loss == plain.loss
    assert_array_equal(r.grad_x, plain.grad_x)
    assert_array_equal(r.grad_y, plain.grad_y)
