"""Tests for geofit.pytorch3d: the tape (Tensor.backward) against geofit's analytic ``(value,
grad)`` functions, finite differences of every vjp the layer adds, the optimisers, the
structures' PyTorch3D semantics and the error messages.

Non-differentiable choices (tested away from them): the nearest neighbours of the chamfer
distance, the faces drawn by the sampler, which faces a pixel keeps in the soft rasterizer.
"""
from __future__ import annotations

import numpy as np
import pytest

import geofit
from geofit import loss as gl
from geofit.ops import sampling as gsampling
from geofit.pytorch3d import optim
from geofit.pytorch3d.loss import (
    chamfer_distance,
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
)
from geofit.pytorch3d.ops import sample_points_from_meshes
from geofit.pytorch3d.renderer import (
    BlendParams,
    FoVPerspectiveCameras,
    MeshRasterizer,
    MeshRenderer,
    PointLights,
    RasterizationSettings,
    SoftPhongShader,
    SoftSilhouetteShader,
    TexturesVertex,
    look_at_view_transform,
)
from geofit.pytorch3d.structures import Meshes, Pointclouds
from geofit.pytorch3d.tensor import (
    Parameter,
    Tensor,
    cat,
    full,
    no_grad,
    ones_like,
    stack,
    tensor,
    zeros,
)
from geofit.pytorch3d.utils import ico_sphere
from geofit.render import soft as gsoft

TOL = 1e-10
# geofit's sampler with the sparse Jacobian B (its name after the PyTorch3D-style return change)
_sampled = getattr(gsampling, "sample_points_with_jacobian", None) or \
    gsampling.sample_points_from_meshes


def _perturbed_sphere(level=2, seed=0, amp=0.05):
    m = geofit.ico_sphere(level)
    rng = np.random.default_rng(seed)
    return m.offset_verts(amp * rng.normal(size=m.verts.shape))


def _fd(fun, x0, eps=1e-6, n=12, seed=0):
    """Central differences of scalar ``fun`` at ``x0`` along ``n`` random coordinates."""
    rng = np.random.default_rng(seed)
    idx = rng.choice(x0.size, size=min(n, x0.size), replace=False)
    out = []
    for i in idx:  # a few coordinates
        e = np.zeros(x0.size)
        e[i] = eps
        e = e.reshape(x0.shape)
        out.append((fun(x0 + e) - fun(x0 - e)) / (2 * eps))
    return idx, np.array(out)


def _tape_grad(fun, x0):
    p = Parameter(x0)
    fun(p).backward()
    return p.grad.numpy()


def _check_fd(fun, x0, rtol=1e-6, atol=1e-8):
    """The tape gradient of ``fun(Parameter)`` against central differences."""
    g = _tape_grad(fun, x0)
    idx, fd = _fd(lambda x: float(fun(Tensor(x))), x0)
    np.testing.assert_allclose(g.ravel()[idx], fd, rtol=rtol, atol=atol)


# ------------------------------------------------------------------------------- the tape
@pytest.mark.parametrize("name, fun", [
    ("add-sub", lambda x: ((x + 2.0) - (3.0 - x) + x).sum()),
    ("mul-div", lambda x: (x * x / (x + 5.0) * 2.0 / 3.0).sum()),
    ("rtruediv", lambda x: (1.0 / (x + 4.0)).sum()),
    ("rpow", lambda x: (2.0 ** x).sum()),
    ("pow", lambda x: ((x ** 2) + (x + 4.0) ** 1.5).mean()),
    ("abs-neg", lambda x: (-(x - 0.1).abs()).sum()),
    ("sum-dim", lambda x: (x.sum(0) ** 2).sum() + (x.sum(1, keepdim=True) ** 2).mean()),
    ("mean-dim", lambda x: (x.mean(dim=1) ** 2).sum()),
    ("index", lambda x: (x[1:, 2] ** 2).sum() + (x[[0, 0, 2]] ** 2).sum() + x[..., 1].mean()),
    ("reshape", lambda x: (x.reshape(-1) * np.arange(12.0)).sum()
     + (x.view(2, 6)[1] ** 2).sum()),
    ("squeeze", lambda x: (x.unsqueeze(0).squeeze() ** 2).sum()
     + (x[None].squeeze(0) * 2.0).sum()),
    ("unbind", lambda x: sum((t ** 2).sum() * (i + 1.0) for i, t in enumerate(x.unbind(1)))),
    ("cat-stack", lambda x: (cat([x, x * 2.0]) ** 2).sum() + (stack([x, -x], 1) ** 3).sum()),
    ("broadcast", lambda x: ((x * tensor([1.0, 2.0, 3.0]) + x.mean(0)) ** 2).sum()),
    ("numpy-left", lambda x: (np.float64(2.0) * x + np.ones(3) - x / np.float64(3.0)).sum()),
    ("clone", lambda x: (x.clone() ** 2).sum()),
    ("torch-index", lambda x: (x[1, ..., range(2)] ** 2).sum() + (x[[0, 3], 1] ** 3).sum()),
])
def test_tape_arithmetic_matches_finite_differences(name, fun):
    """Every recorded arithmetic vjp equals central differences (float64)."""
    x0 = np.random.default_rng(1).normal(size=(4, 3))
    _check_fd(fun, x0)


def test_tape_accumulates_a_parameter_used_twice_and_backward_twice():
    """Gradients add up over uses in one graph and over two backward calls (torch's rule)."""
    p = Parameter(np.array([1.0, -2.0]))
    loss = (p * 3.0).sum() + (p ** 2).sum()
    loss.backward()
    np.testing.assert_allclose(p.grad.numpy(), 3.0 + 2 * p.data)
    loss.backward()
    np.testing.assert_allclose(p.grad.numpy(), 2 * (3.0 + 2 * p.data))


def test_no_grad_records_nothing_and_detach_cuts_the_graph():
    p = Parameter(np.ones(3))
    with no_grad():
        y = (p * 2.0).sum()
    assert not y.requires_grad
    z = (p.detach() * 2.0).sum() + p.sum()
    z.backward()
    np.testing.assert_array_equal(p.grad.numpy(), np.ones(3))


def test_tensor_torch_conveniences():
    """The methods the tutorials call: to, cpu, detach, clone, numpy, item, max(dim), unbind."""
    t = tensor([[1.0, -3.0], [2.0, 5.0]])
    assert t.to("cpu") is t and t.cpu() is t
    values, indices = t.abs().max(0)
    np.testing.assert_array_equal(values.numpy(), [2.0, 5.0])
    np.testing.assert_array_equal(indices.numpy(), [1, 1])
    assert float(max(t.abs().max(0)[0])) == 5.0
    assert "%.3f" % t.sum() == "5.000"
    assert t.size() == (2, 2) and t.size(1) == 2 and len(t) == 2
    assert float(t.mean(0)[0]) == 1.5
    x, y = t.unbind(1)
    np.testing.assert_array_equal(x.numpy(), [1.0, 2.0])
    assert isinstance(np.exp(t), Tensor)
    assert full([1, 4, 3], 0.5).shape == (1, 4, 3)
    assert zeros(2, 3).shape == (2, 3) and ones_like(t).numpy().sum() == 4


def test_tensor_errors_say_what_to_do():
    """numpy on a tensor that needs a gradient raises instead of dropping it silently."""
    p = Parameter(np.ones(3))
    with pytest.raises(TypeError, match="tape does not record"):
        np.exp(p)
    with pytest.raises(RuntimeError, match="detach"):
        p.numpy()
    with pytest.raises(RuntimeError, match="does not require a gradient"):
        tensor(1.0).backward()
    with pytest.raises(RuntimeError, match="gradient is needed"):
        (p * 2.0).backward()
    with pytest.raises(TypeError, match="tape records no gradient"):
        p.max()
    with pytest.raises(TypeError, match="constant exponent"):
        p ** Parameter(np.ones(3))
    with pytest.raises(TypeError, match="floating point"):
        Tensor(np.arange(3), requires_grad=True)
    with pytest.raises(RuntimeError, match="leaf"):
        (p * 2.0).requires_grad_()


# ------------------------------------------------------------------------------- optimisers
def test_sgd_momentum_is_torchs_rule():
    """Two steps of SGD(lr, momentum) on a quadratic give PyTorch's closed-form iterates."""
    p = Parameter(np.array([1.0, 2.0]))
    opt = optim.SGD([p], lr=0.1, momentum=0.9)
    x = p.data.copy()
    b = None
    for _ in range(3):  # steps
        opt.zero_grad()
        (p ** 2).sum().backward()
        opt.step()
        g = 2 * x
        b = g if b is None else 0.9 * b + g
        x = x - 0.1 * b
    np.testing.assert_allclose(p.data, x, rtol=1e-15)


def test_adam_first_step_moves_by_lr_against_the_gradient_sign():
    p = Parameter(np.array([1.0, -2.0]))
    opt = optim.Adam([p], lr=0.1)
    opt.zero_grad()
    (p * tensor([3.0, -5.0])).sum().backward()
    opt.step()
    np.testing.assert_allclose(p.data, [0.9, -1.9], rtol=1e-7)
    opt.param_groups[0]["lr"] = 0.01
    opt.zero_grad()
    (p * tensor([3.0, -5.0])).sum().backward()
    opt.step()
    np.testing.assert_allclose(p.data, [0.89, -1.89], rtol=1e-6)


def test_optimizer_validation():
    with pytest.raises(TypeError, match="requires_grad=True"):
        optim.SGD([tensor([1.0])], lr=1.0)
    with pytest.raises(ValueError, match="non-empty"):
        optim.SGD([], lr=1.0)
    with pytest.raises(ValueError, match="lr"):
        optim.SGD([Parameter(np.ones(1))], lr=0.0)
    with pytest.raises(ValueError, match="nesterov"):
        optim.SGD([Parameter(np.ones(1))], lr=1.0, nesterov=True)
    with pytest.raises(ValueError, match="groups"):
        optim.SGD([{"params": []}], lr=1.0)
    with pytest.raises(ValueError, match="weight_decay"):
        optim.Adam([Parameter(np.ones(1))], weight_decay=0.1)


# ------------------------------------------------------------------------------- losses
def _src_and_param(level=2, seed=0):
    base = _perturbed_sphere(level, seed)
    src = Meshes(verts=[base.verts], faces=[base.faces])
    rng = np.random.default_rng(seed + 10)
    d = Parameter(0.01 * rng.normal(size=base.verts.shape))
    return base, src, d


@pytest.mark.parametrize("name, ours, theirs", [
    ("edge", lambda m: mesh_edge_loss(m), lambda m: gl.mesh_edge_loss(m)),
    ("edge-target", lambda m: mesh_edge_loss(m, 0.1), lambda m: gl.mesh_edge_loss(m, 0.1)),
    ("normal", mesh_normal_consistency, gl.mesh_normal_consistency),
    ("laplacian-uniform", lambda m: mesh_laplacian_smoothing(m, method="uniform"),
     lambda m: gl.mesh_laplacian_smoothing(m, "uniform")),
    ("laplacian-cot", lambda m: mesh_laplacian_smoothing(m, method="cot"),
     lambda m: gl.mesh_laplacian_smoothing(m, "cot")),
])
def test_mesh_regularisers_on_the_tape_equal_the_analytic_gradients(name, ours, theirs):
    """offset_verts(param) -> loss -> backward gives geofit's (value, grad) to 1e-10."""
    base, src, d = _src_and_param()
    loss = ours(src.offset_verts(d))
    loss.backward()
    value, grad = theirs(base.offset_verts(d.data))
    assert abs(float(loss.detach()) - value) <= TOL * max(1.0, abs(value))
    np.testing.assert_allclose(d.grad.numpy(), grad, rtol=0, atol=TOL)


def test_mesh_losses_of_a_batch_average_over_members():
    """A two-mesh batch: the loss is the mean of the members', packed gradient."""
    a, b = _perturbed_sphere(1, 0), _perturbed_sphere(2, 1)
    d = Parameter(np.zeros((a.n_verts + b.n_verts, 3)))
    m = Meshes(verts=[a.verts, b.verts], faces=[a.faces, b.faces]).offset_verts(d)
    loss = mesh_edge_loss(m)
    loss.backward()
    va, ga = gl.mesh_edge_loss(a)
    vb, gb = gl.mesh_edge_loss(b)
    assert abs(float(loss.detach()) - (va + vb) / 2) < TOL
    np.testing.assert_allclose(d.grad.numpy(), np.concatenate([ga, gb]) / 2, atol=TOL)


def _chamfer_reference(x, y, **kw):
    r = gl.chamfer_distance(x, y, **kw)
    return r.loss, r.grad_x, r.grad_y


@pytest.mark.parametrize("kw", [{}, {"point_reduction": "sum"}, {"norm": 1},
                                {"single_directional": True}])
def test_chamfer_on_the_tape_equals_the_analytic_gradient(kw):
    rng = np.random.default_rng(3)
    x = Parameter(rng.normal(size=(2, 50, 3)))
    y = Parameter(rng.normal(size=(2, 40, 3)))
    loss, loss_n = chamfer_distance(x, y, **kw)
    assert loss_n is None
    loss.backward()
    value, gx, gy = _chamfer_reference(x.data, y.data, **kw)
    assert abs(float(loss.detach()) - value) < TOL
    np.testing.assert_allclose(x.grad.numpy(), gx, atol=TOL)
    np.testing.assert_allclose(y.grad.numpy(), gy, atol=TOL)


def test_chamfer_per_member_and_normal_terms_on_the_tape():
    """batch_reduction=None: the vjp of g . loss scales member b by g[b]; normals get theirs."""
    rng = np.random.default_rng(4)
    x = Parameter(rng.normal(size=(3, 30, 3)))
    y = rng.normal(size=(3, 20, 3))
    xn = Parameter(rng.normal(size=(3, 30, 3)))
    yn = rng.normal(size=(3, 20, 3))
    w = np.array([1.0, 2.0, 3.0])
    loss, loss_n = chamfer_distance(x, y, x_normals=xn, y_normals=yn, batch_reduction=None)
    ((loss * w).sum() + (loss_n * w).sum()).backward()
    r = gl.chamfer_distance(x.data, y, x_normals=xn.data, y_normals=yn, batch_reduction=None)
    gx = np.stack([gl.chamfer_distance(x.data[b], y[b]).grad_x for b in range(3)])
    np.testing.assert_allclose(loss.detach().numpy(), r.loss, atol=TOL)
    np.testing.assert_allclose(x.grad.numpy(), gx * w[:, None, None], atol=TOL)
    gxn = np.stack([gl.chamfer_distance(x.data[b], y[b], x_normals=xn.data[b],
                                        y_normals=yn[b]).grad_x_normals for b in range(3)])
    np.testing.assert_allclose(xn.grad.numpy(), gxn * w[:, None, None], atol=TOL)


def test_chamfer_accepts_pointclouds_and_checks_lengths():
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(20, 3)), rng.normal(size=(30, 3))
    loss, _ = chamfer_distance(Pointclouds([a]), Pointclouds([b]))
    assert abs(float(loss) - gl.chamfer_distance(a, b).loss) < TOL
    with pytest.raises(ValueError, match="x_lengths"):
        chamfer_distance(Pointclouds([a]), Pointclouds([b]), x_lengths=[20])


def test_sampling_on_the_tape_is_the_sparse_jacobian():
    """d/dV sum(W * samples) = B^T W with geofit's sampling matrix for the same seed."""
    base, src, d = _src_and_param()
    W = np.random.default_rng(7).normal(size=(1, 300, 3))
    pts = sample_points_from_meshes(src.offset_verts(d), 300, seed=11)
    (pts * W).sum().backward()
    s = _sampled(base.offset_verts(d.data), 300, seed=11)
    np.testing.assert_allclose(pts.detach().numpy()[0], s.points, atol=TOL)
    np.testing.assert_allclose(d.grad.numpy(), s.B.T @ W[0], atol=TOL)


def test_sampling_textures_and_normals():
    """TexturesVertex samples are B @ features with gradient B^T g; normals are unit."""
    m = ico_sphere(1)
    feats = Parameter(np.random.default_rng(0).random((1, 42, 3)))
    m.textures = TexturesVertex(verts_features=feats)
    pts, nrm, tex = sample_points_from_meshes(m, 200, return_normals=True,
                                              return_textures=True, seed=3)
    s = _sampled(geofit.ico_sphere(1), 200, seed=3)
    np.testing.assert_allclose(tex.detach().numpy()[0], s.B @ feats.data[0], atol=TOL)
    np.testing.assert_allclose(np.linalg.norm(nrm.numpy(), axis=-1), 1.0, atol=1e-12)
    tex.sum().backward()
    np.testing.assert_allclose(feats.grad.numpy()[0], s.B.T @ np.ones((200, 3)), atol=TOL)
    with pytest.raises(ValueError, match="no textures"):
        sample_points_from_meshes(ico_sphere(1), 10, return_textures=True)


def test_tutorial_one_objective_equals_the_weighted_analytic_sum():
    """The deform tutorial's weighted sum on the tape equals the weighted analytic gradients."""
    base, src, d = _src_and_param(3)
    trg = _perturbed_sphere(2, 5, 0.2)
    new = src.offset_verts(d)
    a = sample_points_from_meshes(Meshes([trg.verts], [trg.faces]), 500, seed=1)
    b = sample_points_from_meshes(new, 500, seed=2)
    loss_chamfer, _ = chamfer_distance(a, b)
    loss = (loss_chamfer * 1.0 + mesh_edge_loss(new) * 1.0 + mesh_normal_consistency(new) * 0.01
            + mesh_laplacian_smoothing(new, method="uniform") * 0.1)
    loss.backward()
    mesh = base.offset_verts(d.data)
    sb = _sampled(mesh, 500, seed=2)
    sa = _sampled(trg, 500, seed=1)
    _, _, gy = _chamfer_reference(sa.points, sb.points)
    grad = (sb.B.T @ gy + gl.mesh_edge_loss(mesh)[1] + 0.01 * gl.mesh_normal_consistency(mesh)[1]
            + 0.1 * gl.mesh_laplacian_smoothing(mesh, "uniform")[1])
    np.testing.assert_allclose(d.grad.numpy(), grad, atol=TOL)


# ------------------------------------------------------------------------------- structures
def test_offset_and_scale_verts_on_the_tape():
    """offset_verts adds, scale_verts(_) multiply (per mesh for an (N,) scale), exact vjps."""
    base, src, d = _src_and_param(1)
    (src.offset_verts(d).verts_packed() ** 2).sum().backward()
    np.testing.assert_allclose(d.grad.numpy(), 2 * (base.verts + d.data), atol=TOL)
    _check_fd(lambda x: (src.offset_verts(x).scale_verts(1.5).verts_padded() ** 3).sum(),
              d.data)
    two = Meshes([base.verts, base.verts], [base.faces, base.faces])
    s = Parameter(np.array([2.0, 3.0]))
    (two.scale_verts(s).verts_packed()).sum().backward()
    np.testing.assert_allclose(s.grad.numpy(), base.verts.sum() * np.ones(2), atol=1e-9)
    m = Meshes([base.verts], [base.faces])
    m.offset_verts_(-tensor(base.verts.mean(0)))
    m.scale_verts_(0.5)
    np.testing.assert_allclose(m.verts_packed().numpy(),
                               (base.verts - base.verts.mean(0)) * 0.5, atol=1e-15)


def test_meshes_views_extend_and_update_padded():
    """Packed / padded / list views agree; extend repeats each mesh consecutively."""
    a, b = geofit.ico_sphere(0), geofit.ico_sphere(1)
    m = Meshes(verts=[a.verts, b.verts], faces=[a.faces, b.faces])
    assert m.verts_padded().shape == (2, 42, 3)
    assert m.faces_padded().shape == (2, 80, 3) and int(m.faces_padded().numpy()[0, -1, 0]) == -1
    np.testing.assert_array_equal(m.faces_packed().numpy()[20:], b.faces + 12)
    v, f = m.get_mesh_verts_faces(1)
    np.testing.assert_array_equal(v.numpy(), b.verts)
    e = m.extend(2)
    assert len(e) == 4 and e.num_verts_per_mesh().tolist() == [12, 12, 42, 42]
    p = Parameter(m.verts_padded().numpy())
    moved = m.update_padded(p * 2.0)
    np.testing.assert_allclose(moved.verts_list()[1].detach().numpy(), 2 * b.verts)
    moved.verts_packed().sum().backward()
    assert p.grad.numpy()[0, 12:].sum() == 0.0 and p.grad.numpy()[1].sum() == 2 * 42 * 3
    assert len(m[1]) == 1 and m[1].verts_packed().shape == (42, 3)
    np.testing.assert_allclose(np.linalg.norm(m.verts_normals_packed().numpy(), axis=1), 1.0)
    padded = Meshes(verts=tensor(np.stack([b.verts, b.verts])),
                    faces=tensor(np.stack([b.faces, np.vstack([a.faces, -np.ones((60, 3))])])))
    assert padded.num_faces_per_mesh().tolist() == [80, 20]


def test_structures_validation():
    v, f = geofit.ico_sphere(0).verts, geofit.ico_sphere(0).faces
    m = Meshes([v], [f])
    with pytest.raises(ValueError, match="vert_offsets_packed"):
        m.offset_verts(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="scale"):
        m.scale_verts(np.ones(3))
    with pytest.raises(ValueError, match="face arrays"):
        Meshes([v, v], [f])
    with pytest.raises(ValueError, match="index"):
        m.get_mesh_verts_faces(3)
    with pytest.raises(ValueError, match="N:"):
        m.extend(0)
    with pytest.raises(ValueError, match="new_verts_padded"):
        m.update_padded(np.zeros((1, 5, 3)))
    with pytest.raises(ValueError, match="padded"):
        Meshes(np.zeros((12, 3)), [f])
    with pytest.raises(ValueError, match="per-vertex features"):
        m.textures = TexturesVertex(verts_features=np.ones((1, 5, 3)))
    with pytest.raises(TypeError, match="TexturesVertex or TexturesUV"):
        m.textures = geofit.TexturesVertex(np.ones((12, 3)))
    with pytest.raises(ValueError, match="one row per point"):
        Pointclouds([np.zeros((4, 3))], features=[np.zeros((3, 3))])


def test_open3d_and_trimesh_objects_get_a_conversion_hint():
    """Passing an Open3D or trimesh mesh where arrays are expected says how to convert."""
    trimesh = pytest.importorskip("trimesh")
    o3d = pytest.importorskip("open3d")
    tm = trimesh.creation.icosphere(1)
    with pytest.raises(TypeError, match=r"mesh\.vertices"):
        Meshes(verts=[tm], faces=[tm.faces])
    om = o3d.geometry.TriangleMesh.create_sphere()
    with pytest.raises(TypeError, match="np.asarray"):
        Meshes(verts=om, faces=[np.zeros((1, 3), np.int64)])
    with pytest.raises(TypeError, match="np.asarray"):
        Pointclouds(points=[o3d.geometry.PointCloud()])


# ------------------------------------------------------------------------------- renders
def _cams(n=2, size=24):
    R, T = look_at_view_transform(dist=2.7, elev=np.array([10.0, 40.0])[:n],
                                  azim=np.array([30.0, 160.0])[:n])
    return FoVPerspectiveCameras(R=R, T=T), size


def _soft_settings(size):
    return RasterizationSettings(image_size=size, blur_radius=np.log(1.0 / 1e-4 - 1.0) * 1e-4,
                                 faces_per_pixel=20)


def test_soft_silhouette_render_and_loss_equal_the_analytic_vjp():
    """((silhouette - target)**2).mean() on the tape = the renderer's vjp of the same loss."""
    cams, size = _cams()
    base, src, d = _src_and_param(2, 1)
    target = np.random.default_rng(2).random((2, size, size))
    r = MeshRenderer(MeshRasterizer(cameras=cams, raster_settings=_soft_settings(size)),
                     SoftSilhouetteShader(BlendParams(sigma=1e-4)))
    images = r(src.offset_verts(d))
    loss = ((images[..., 3] - target) ** 2).mean()
    loss.backward()
    mesh = base.offset_verts(d.data)
    ref = gsoft.SoftSilhouetteRenderer(cams, _soft_settings(size)._soft())(mesh)
    np.testing.assert_allclose(images.detach().numpy(), ref.images, atol=1e-14)
    g = 2 * (ref.silhouettes - target) / target.size
    np.testing.assert_allclose(d.grad.numpy(), ref.vjp(g).verts, atol=TOL)
    assert np.abs(d.grad.numpy()).max() > 1e-6


def test_soft_silhouette_batch_of_meshes_per_camera():
    """N meshes with N cameras: mesh i by camera i, gradients to each member's rows."""
    cams, size = _cams()
    a, b = _perturbed_sphere(1, 0), _perturbed_sphere(1, 1)
    d = Parameter(np.zeros((a.n_verts * 2, 3)))
    m = Meshes([a.verts, b.verts], [a.faces, b.faces]).offset_verts(d)
    r = MeshRenderer(MeshRasterizer(raster_settings=_soft_settings(size)), SoftSilhouetteShader())
    images = r(m, cameras=cams)
    (images[..., 3] ** 2).sum().backward()
    s = _soft_settings(size)._soft()
    for i, mesh in enumerate((a, b)):  # members
        ref = gsoft.SoftSilhouetteRenderer(cams[i], s)(mesh)
        np.testing.assert_allclose(images.detach().numpy()[i], ref.images[0], atol=1e-14)
        np.testing.assert_allclose(d.grad.numpy()[i * a.n_verts:(i + 1) * a.n_verts],
                                   ref.vjp(2 * ref.silhouettes).verts, atol=TOL)


def test_soft_phong_render_equals_the_analytic_vjp_to_positions_and_colours():
    cams, size = _cams(1)
    base, src, d = _src_and_param(2, 2)
    rgb = Parameter(np.full((1, base.n_verts, 3), 0.5)
                    + 0.1 * np.random.default_rng(0).random((1, base.n_verts, 3)))
    lights = PointLights(location=[[0.0, 1.0, -3.0]])
    r = MeshRenderer(MeshRasterizer(cameras=cams, raster_settings=_soft_settings(size)),
                     SoftPhongShader(cameras=cams, lights=lights))
    new = src.offset_verts(d)
    new.textures = TexturesVertex(verts_features=rgb)
    images = r(new)
    target = np.random.default_rng(3).random((1, size, size, 3))
    ((images[..., :3] - target) ** 2).mean().backward()
    ref = gsoft.SoftPhongRenderer(cams, lights, raster_settings=_soft_settings(size)._soft())(
        base.offset_verts(d.data), rgb.data[0])
    np.testing.assert_allclose(images.detach().numpy(), ref.images, atol=1e-14)
    g = np.zeros(ref.images.shape)
    g[..., :3] = 2 * (ref.images[..., :3] - target) / target.size
    grads = ref.vjp(g)
    np.testing.assert_allclose(d.grad.numpy(), grads.verts, atol=TOL)
    np.testing.assert_allclose(rgb.grad.numpy()[0], grads.colors, atol=TOL)


def test_soft_render_finite_differences_through_the_tape():
    """The whole silhouette objective (render + loss) against central differences."""
    cams, size = _cams(1, 16)
    base, src, d = _src_and_param(1, 3)
    r = MeshRenderer(MeshRasterizer(cameras=cams, raster_settings=_soft_settings(size)),
                     SoftSilhouetteShader())
    target = np.random.default_rng(1).random((1, size, size))

    def fun(x):
        return ((r(src.offset_verts(x))[..., 3] - target) ** 2).mean()

    g = _tape_grad(fun, d.data)
    idx, fd = _fd(lambda x: float(fun(Tensor(x))), d.data, eps=1e-7)
    np.testing.assert_allclose(g.ravel()[idx], fd, rtol=1e-4, atol=1e-9)


def test_hard_render_and_errors_for_what_is_not_differentiable():
    """blur 0 / K 1 uses the hard renderer; gradients through it raise with the way out."""
    cams, size = _cams(1)
    m = ico_sphere(2)
    m.textures = TexturesVertex(verts_features=np.full((1, 162, 3), 0.7))
    hard = MeshRenderer(MeshRasterizer(cameras=cams, raster_settings=RasterizationSettings(
        image_size=size)), SoftPhongShader(cameras=cams))
    images = hard(m)
    assert images.shape == (1, size, size, 4)
    assert float(images[0, 0, 0, 3]) == 0.0 and float(images[0, size // 2, size // 2, 3]) > 0.5
    from geofit.pytorch3d.renderer import HardFlatShader

    flat = MeshRenderer(MeshRasterizer(cameras=cams, raster_settings=_soft_settings(size)),
                        HardFlatShader(cameras=cams))
    with pytest.raises(NotImplementedError, match="SoftSilhouetteShader"):
        flat(m)
    with pytest.raises(ValueError, match="cameras"):
        MeshRenderer(MeshRasterizer(), SoftSilhouetteShader())(m)
    with pytest.raises(TypeError, match="Meshes"):
        hard(geofit.ico_sphere(1))
    with pytest.raises(TypeError, match="MeshRasterizer"):
        MeshRenderer(object(), SoftSilhouetteShader())
    with pytest.raises(TypeError, match="RasterizationSettings"):
        MeshRasterizer(raster_settings=geofit.render.RasterizationSettings())


# ------------------------------------------------------------------------------- missing names
@pytest.mark.parametrize("module, name, hint", [
    ("geofit.pytorch3d.renderer", "PulsarPointsRenderer", "AlphaCompositor"),
    ("geofit.pytorch3d.ops", "knn_points", "cKDTree"),
    ("geofit.pytorch3d.vis.plotly_vis", "plot_batch_individually", "plot_scene"),
    ("geofit.pytorch3d.nn", "Conv2d", "NeuralRadianceField"),
    ("geofit.pytorch3d.renderer", "NoSuchThing", "six introductory tutorials"),
])
def test_missing_pytorch3d_names_say_what_to_use(module, name, hint):
    """module.Name -> AttributeError, from module import Name -> ImportError, both with a hint."""
    import importlib

    mod = importlib.import_module(module)
    with pytest.raises(AttributeError, match=hint):
        getattr(mod, name)
    with pytest.raises(ImportError, match=hint):
        exec(f"from {module} import {name}", {})
    assert not hasattr(mod, name)


# ------------------------------------------------------------------------------- volumes (5, 6)
def test_volume_and_implicit_renderers_give_geofits_images():
    """VolumeRenderer(cameras=, volumes=) and ImplicitRenderer(volumetric_function=) forward."""
    from geofit.pytorch3d.renderer import (
        EmissionAbsorptionRaymarcher,
        ImplicitRenderer,
        MonteCarloRaysampler,
        NDCMultinomialRaysampler,
        VolumeRenderer,
        ray_bundle_to_ray_points,
    )
    from geofit.pytorch3d.structures import Volumes
    from geofit.structures.volume import Volume

    R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    sampler = NDCMultinomialRaysampler(image_width=12, image_height=12, n_pts_per_ray=24,
                                       min_depth=0.1, max_depth=4.0)
    rng = np.random.default_rng(0)
    dens = rng.random((2, 1, 6, 6, 6)) * 0.3
    feats = rng.random((2, 3, 6, 6, 6))
    r = VolumeRenderer(raysampler=sampler, raymarcher=EmissionAbsorptionRaymarcher())
    images, bundle = r(cameras=cams, volumes=Volumes(densities=dens, features=feats,
                                                      voxel_size=0.3))
    assert images.shape == (2, 12, 12, 4)
    for i in range(2):  # camera i renders volume i
        ref = r._r.render_rays(Volume(dens[i, 0], feats[i], voxel_size=0.3),
                               type(bundle)(*(np.asarray(a)[i:i + 1] for a in bundle)))
        np.testing.assert_allclose(images.numpy()[i], ref[0], atol=1e-14)
    ir = ImplicitRenderer(raysampler=MonteCarloRaysampler(-1, 1, -1, 1, n_rays_per_image=30,
                                                          n_pts_per_ray=16, min_depth=0.1,
                                                          max_depth=3.0),
                          raymarcher=EmissionAbsorptionRaymarcher())

    def volumetric_function(ray_bundle, cameras, **kwargs):
        pts = ray_bundle_to_ray_points(ray_bundle).numpy()
        inside = np.linalg.norm(pts, axis=-1, keepdims=True) < 1.0
        return inside * 0.2, np.ones(pts.shape[:-1] + (3,))

    out, b = ir(cameras=cams, volumetric_function=volumetric_function, seed=0)
    assert out.shape == (2, 30, 4)
    hit = np.linalg.norm(np.asarray(b.xys), axis=-1) < 0.3  # rays through the ball's centre
    assert np.all(out.numpy()[hit][:, 3] > 0.5)
    with pytest.raises(ValueError, match="densities"):
        Volumes(densities=np.zeros((6, 6, 6)))
    with pytest.raises(TypeError, match="Volumes"):
        r(cameras=cams, volumes=Volume(dens[0, 0]))


def test_docstring_examples_run():
    """The Examples sections of geofit.pytorch3d run as doctests."""
    import doctest
    import importlib

    for name in ("tensor", "structures", "utils", "renderer.cameras"):  # modules with examples
        mod = importlib.import_module(f"geofit.pytorch3d.{name}")
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.attempted > 0 and result.failed == 0, name


def test_custom_objective_guide_runs(tmp_path, monkeypatch):
    """docs/custom_objective.md: its python blocks run in order (their asserts check the fits
    and the finite-difference checks)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "custom_objective.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 5
    monkeypatch.chdir(tmp_path)
    ns = {"__name__": "guide"}
    for i, block in enumerate(blocks):  # the guide's blocks, in order
        exec(compile(block, f"custom_objective.md block {i}", "exec"), ns)


def test_tape_sigmoid_sqrt_clamp_expand_split_match_finite_differences():
    """The ops the volume tutorial adds to the tape (its huber: clamp(1e-4).sqrt())."""
    from geofit.pytorch3d.tensor import sigmoid

    def fun(x):
        a, b = sigmoid(x).expand(3, 4, 3).split([2, 1], dim=-1)
        huber = ((1 + (a - 0.3) ** 2 / 0.01).clamp(1e-4).sqrt() - 1) * 0.1
        return huber.abs().mean() + (b.exp() * x[None, :, 2:]).clamp(max=1.5).sum()

    _check_fd(fun, np.random.default_rng(2).normal(size=(4, 3)))
    with pytest.raises(ValueError, match="sum to"):
        tensor(np.ones((2, 3))).split([1, 1], dim=1)
    p = Parameter(np.ones(3))
    with pytest.raises(TypeError, match="in-place"):
        p[0] = 2.0


def test_volume_render_on_the_tape_equals_geofits_vjp():
    """A VolumeModel-style expand of one volume: the tape gives VolumeRenderer.vjp."""
    from geofit.pytorch3d.renderer import (
        EmissionAbsorptionRaymarcher,
        NDCMultinomialRaysampler,
        VolumeRenderer,
    )
    from geofit.pytorch3d.structures import Volumes
    from geofit.structures.volume import Volume

    R, T = look_at_view_transform(2.0, 10.0, [0.0, 70.0, 150.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    r = VolumeRenderer(raysampler=NDCMultinomialRaysampler(
        image_width=10, image_height=10, n_pts_per_ray=20, min_depth=0.5, max_depth=3.5),
        raymarcher=EmissionAbsorptionRaymarcher())
    rng = np.random.default_rng(0)
    dens = Parameter(rng.random((1, 5, 5, 5)) * 0.4)
    cols = Parameter(rng.random((3, 5, 5, 5)))
    W = rng.normal(size=(3, 10, 10, 4))
    vols = Volumes(densities=dens[None].expand(3, *dens.shape),
                   features=cols[None].expand(3, *cols.shape), voxel_size=0.3)
    images, bundle = r(cameras=cams, volumes=vols)
    (images * W).sum().backward()
    ref = r._r.vjp(W, Volume(dens.data[0], cols.data, voxel_size=0.3), bundle)
    np.testing.assert_allclose(dens.grad.numpy()[0], ref.densities, atol=TOL)
    np.testing.assert_allclose(cols.grad.numpy(), ref.features, atol=TOL)
    two = Parameter(rng.random((3, 1, 5, 5, 5)) * 0.4)  # three different volumes

    def fun(d):
        return (r(cameras=cams, volumes=Volumes(densities=d, features=np.ones((3, 3, 5, 5, 5)),
                                                 voxel_size=0.3))[0] * W).sum()

    _check_fd(fun, two.data)


# ------------------------------------------------------------------------------- NeRF pieces (6)
def test_nn_layers_and_normalize_match_finite_differences():
    """Linear / Softplus / Sigmoid / ReLU / Sequential / normalize / sin / cos on the tape."""
    from geofit.pytorch3d import nn
    from geofit.pytorch3d.tensor import manual_seed

    manual_seed(0)
    net = nn.Sequential(nn.Linear(6, 5), nn.Softplus(beta=10.0), nn.Linear(5, 4), nn.ReLU(),
                        nn.Linear(4, 2), nn.Sigmoid())
    assert len(net.parameters()) == 6 and net[0].weight.shape == (5, 6)

    def fun(x):
        d = nn.functional.normalize(x[..., :3], dim=-1)
        h = cat([d.sin(), (x[..., 3:] * 2.0).cos()], dim=-1)
        return (net(h) ** 2).sum() + x.log().sum() * 0.0 + (x ** 2).sum() * 0.1

    x0 = np.random.default_rng(1).random((2, 4, 6)) + 0.1
    _check_fd(fun, x0)
    w0 = net[0].weight.data.copy()

    def loss_at(w):  # the network's output as a function of its first layer's weight
        net[0].weight.data[...] = w
        return float((net(Tensor(x0)) ** 2).sum())

    net[0].weight.data[...] = w0
    net[0].weight.grad = None  # _check_fd's backward above accumulated into it
    (net(Tensor(x0)) ** 2).sum().backward()
    g = net[0].weight.grad.numpy().copy()
    idx, fd = _fd(loss_at, w0)
    net[0].weight.data[...] = w0
    np.testing.assert_allclose(g.ravel()[idx], fd, rtol=1e-6, atol=1e-9)
    with pytest.raises(ValueError, match="p=2"):
        nn.functional.normalize(np.ones(3), p=1)


def test_implicit_renderer_on_the_tape_equals_the_raymarcher_vjp():
    from geofit.pytorch3d.renderer import (
        EmissionAbsorptionRaymarcher,
        ImplicitRenderer,
        MonteCarloRaysampler,
    )

    R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    marcher = EmissionAbsorptionRaymarcher()
    r = ImplicitRenderer(raysampler=MonteCarloRaysampler(-1, 1, -1, 1, n_rays_per_image=20,
                                                         n_pts_per_ray=8, min_depth=0.5,
                                                         max_depth=3.0),
                         raymarcher=marcher)
    rng = np.random.default_rng(0)
    dens = Parameter(rng.random((2, 20, 8, 1)) * 0.3)
    cols = Parameter(rng.random((2, 20, 8, 3)))
    W = rng.normal(size=(2, 20, 4))
    images, _ = r(cameras=cams, volumetric_function=lambda ray_bundle, cameras: (dens, cols),
                  seed=0)
    (images * W).sum().backward()
    ref = marcher.vjp(W, dens.data, cols.data)
    np.testing.assert_allclose(dens.grad.numpy(), ref.densities, atol=TOL)
    np.testing.assert_allclose(cols.grad.numpy(), ref.features, atol=TOL)


# ------------------------------------------------------------------------------- validators
def _validator_cases():
    from geofit.pytorch3d import io as pio
    from geofit.pytorch3d.renderer import (
        AlphaCompositor,
        EmissionAbsorptionRaymarcher,
        NDCMultinomialRaysampler,
        PointsRasterizationSettings,
        PointsRasterizer,
        PointsRenderer,
        TexturesUV,
        VolumeRenderer,
    )
    from geofit.pytorch3d.structures import Volumes
    from geofit.pytorch3d.vis.texture_vis import texturesuv_image_matplotlib

    s0 = geofit.ico_sphere(0)
    one = Meshes([s0.verts], [s0.faces])
    two = Meshes([s0.verts, s0.verts], [s0.faces, s0.faces])
    cams, size = _cams(2, 8)
    uv = dict(faces_uvs=[s0.faces], verts_uvs=[np.zeros((12, 2))])
    pts_r = PointsRenderer(PointsRasterizer(cams[0], PointsRasterizationSettings(image_size=8)),
                           AlphaCompositor())
    vr = VolumeRenderer(NDCMultinomialRaysampler(image_width=4, image_height=4, n_pts_per_ray=4,
                                                 min_depth=0.1, max_depth=3.0),
                        EmissionAbsorptionRaymarcher())
    soft_uv = Meshes([s0.verts], [s0.faces], textures=TexturesUV(maps=[np.ones((4, 4, 3))], **uv))
    return [
        (ValueError, "texture atlas", lambda: pio.load_obj("x.obj", create_texture_atlas=True)),
        (ValueError, "vn lines", lambda: pio.save_obj("x.obj", s0.verts, s0.faces,
                                                      normals=s0.verts)),
        (TypeError, "Meshes", lambda: mesh_edge_loss(s0)),
        (TypeError, "Meshes", lambda: sample_points_from_meshes(s0, 10)),
        (ValueError, "empty", lambda: sample_points_from_meshes(Meshes([], []), 10)),
        (ValueError, "num_samples", lambda: sample_points_from_meshes(one, 0)),
        (ValueError, "momentum", lambda: optim.SGD([Parameter(np.ones(1))], lr=1.0,
                                                   momentum=-1.0)),
        (TypeError, "array or Tensor", lambda: Meshes([object()], [s0.faces])),
        (ValueError, "scale", lambda: two.scale_verts(Parameter(np.ones(3)))),
        (ValueError, "finite", lambda: one.scale_verts(np.inf)),
        (ValueError, r"\(P, 3\)", lambda: Pointclouds([np.zeros((4, 2))])),
        (ValueError, "expected 1 arrays", lambda: Pointclouds([np.zeros((4, 3))],
                                                              features=[np.ones((4, 3))] * 2)),
        (ValueError, "N:", lambda: Pointclouds([np.zeros((4, 3))]).extend(0)),
        (ValueError, "features", lambda: Volumes(np.zeros((1, 1, 4, 4, 4)),
                                                 features=np.zeros((1, 3, 4, 4, 5)))),
        (TypeError, "floating point", lambda: tensor([1, 2]).requires_grad_()),
        (ValueError, r"\(N, V, C\)", lambda: TexturesVertex(verts_features=np.ones((12, 3)))),
        (ValueError, r"\(V, C\)", lambda: TexturesVertex(verts_features=[np.ones(12)])),
        (ValueError, "bilinear", lambda: TexturesUV(maps=[np.ones((4, 4, 3))],
                                                     sampling_mode="nearest", **uv)),
        (ValueError, "one of each", lambda: TexturesUV(maps=[np.ones((4, 4, 3))] * 2, **uv)),
        (ValueError, "faces_uvs for", lambda: setattr(
            one, "textures", TexturesUV(maps=[np.ones((4, 4, 3))], faces_uvs=[s0.faces[:3]],
                                        verts_uvs=[np.zeros((12, 2))]))),
        (ValueError, "different sizes", lambda: TexturesUV(
            maps=[np.ones((4, 4, 3)), np.ones((5, 4, 3))], faces_uvs=[s0.faces] * 2,
            verts_uvs=[np.zeros((12, 2))] * 2).maps_padded()),
        (ValueError, "1 or 2 volumes", lambda: vr(cameras=cams, volumes=Volumes(
            np.zeros((3, 1, 4, 4, 4))))),
        (ValueError, "one mesh", lambda: MeshRasterizer(cams, _soft_settings(8))(two)),
        (ValueError, "1 or 2 cameras", lambda: MeshRenderer(
            MeshRasterizer(raster_settings=_soft_settings(8)), SoftSilhouetteShader())(
            Meshes([s0.verts] * 2, [s0.faces] * 2), cameras=FoVPerspectiveCameras(
                R=np.stack([np.eye(3)] * 3), T=np.tile([0.0, 0.0, 3.0], (3, 1))))),
        (NotImplementedError, "TexturesVertex", lambda: MeshRenderer(
            MeshRasterizer(cams, _soft_settings(8)), SoftPhongShader(cameras=cams))(soft_uv)),
        (NotImplementedError, "no gradient", lambda: pts_r(Pointclouds(
            [Parameter(np.zeros((3, 3)))], features=[np.ones((3, 3))]))),
        (TypeError, "Pointclouds", lambda: pts_r(np.zeros((3, 3)))),
        (TypeError, "TexturesUV", lambda: texturesuv_image_matplotlib(TexturesVertex(
            verts_features=np.ones((1, 12, 3))))),
    ]


@pytest.mark.parametrize("case", range(len(_validator_cases())))
def test_validators_name_the_argument(case):
    """Every validation branch of geofit.pytorch3d raises with a message naming the problem."""
    exc, match, call = _validator_cases()[case]
    with pytest.raises(exc, match=match):
        call()
