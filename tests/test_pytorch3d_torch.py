"""geofit.pytorch3d.torch: torch's names on the tape, and the PyTorch3D extras it enables
(so3 maps, grid_sample, plot_scene)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import geofit.pytorch3d.torch as torch
from geofit.pytorch3d.transforms import hat, so3_exp_map, so3_exponential_map, so3_log_map


def _fd(fun, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of a scalar function of an array."""
    g = np.zeros_like(x)
    for i in np.ndindex(x.shape):  # every coordinate of a tiny input
        x[i] += h
        up = fun(x)
        x[i] -= 2 * h
        down = fun(x)
        x[i] += h
        g[i] = (up - down) / (2 * h)
    return g


def _check_tape(build, x0: np.ndarray, atol: float) -> None:
    """The tape's gradient of ``build(Parameter(x))`` equals central differences at ``x0``."""
    p = torch.Parameter(x0.copy())
    build(p).backward()
    np.testing.assert_allclose(p.grad.numpy(),
                               _fd(lambda a: float(build(torch.tensor(a))), x0.copy()), atol=atol)


def test_torch_names_the_tutorials_use():
    """device / cuda / dtypes / creation / seeding behave as the tutorials expect."""
    assert torch.cuda.is_available() is False and torch.cuda.device_count() == 0
    with pytest.raises(RuntimeError, match="no CUDA"):
        torch.cuda.set_device(torch.device("cuda:0"))
    d = torch.device("cuda:0")
    assert (d.type, d.index, str(d)) == ("cuda", 0, "cuda:0") and torch.device("cpu") == "cpu"
    x = torch.full((2, 3), 0.5, device=d, requires_grad=True)
    assert x.to(d) is x and x.requires_grad and x.dtype == np.float64
    assert torch.tensor([1, 2], dtype=torch.float32).dtype == np.float64
    assert torch.zeros(2, dtype=torch.long).dtype == np.int64
    torch.manual_seed(3)
    a = (torch.rand(4).numpy(), torch.randn(2, 2).numpy(), torch.randperm(5).numpy())
    torch.manual_seed(3)
    b = (torch.rand(4).numpy(), torch.randn(2, 2).numpy(), torch.randperm(5).numpy())
    for u, v in zip(a, b):  # same seed, same draws
        np.testing.assert_array_equal(u, v)
    assert np.all((a[0] >= 0) & (a[0] < 1)) and sorted(a[2]) == list(range(5))
    assert torch.__version__ == "0+geofit"
    s = torch.zeros(2, 3, 4).shape
    assert s == (2, 3, 4) and s[:-1].numel() == 6 and isinstance(s[:-1], torch.Size)
    assert [len(c) for c in torch.chunk(torch.arange(10), 4)] == [3, 3, 3, 1]
    assert torch.eye(3).numpy().trace() == 3 and torch.is_tensor(torch.ones_like(x))
    assert (torch.arange(3) > 0.5).float().numpy().tolist() == [0.0, 1.0, 1.0]
    assert "%.2f" % torch.tensor(0.25) == "0.25" and int(torch.tensor([7])) == 7


def test_tensor_shape_ops_record_their_gradients():
    """permute, transpose, flatten, chunk: gradients equal central differences."""
    rng = np.random.default_rng(0)
    x0 = rng.normal(size=(2, 3, 4))
    W = rng.normal(size=(4, 2, 3))

    def build(t):
        y = t.permute(2, 0, 1) * W
        z = y.transpose(0, 2).flatten(1).chunk(2, dim=1)[1]
        return (z * z).sum() + (y ** 2).mean()

    _check_tape(build, x0, 1e-7)
    with pytest.raises(TypeError, match="detach"):
        torch.Parameter(x0).long()


def test_so3_exp_map_is_rodrigues_and_matches_scipy():
    """so3_exp_map equals scipy's rotation of the same axis-angle vector (PyTorch3D's
    convention), the old name is the same function, and so3_log_map inverts it."""
    rng = np.random.default_rng(1)
    v = rng.normal(size=(20, 3))
    v *= (rng.uniform(0.05, 3.0, 20) / np.linalg.norm(v, axis=1))[:, None]
    R = so3_exp_map(torch.tensor(v)).numpy()
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R),
                               np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    assert so3_exponential_map is so3_exp_map
    np.testing.assert_allclose(so3_log_map(R).numpy(), v, atol=1e-9)
    np.testing.assert_allclose(hat(v).numpy() @ v[:, :, None], np.zeros((20, 3, 1)), atol=1e-12)
    # below sqrt(eps) PyTorch3D's clamp: the angle in the factors is sqrt(eps), not |v|
    tiny = np.array([[1e-4, 0.0, 0.0]])
    t = np.sqrt(1e-4)
    K = hat(tiny).numpy()[0]
    ref = np.eye(3) + np.sin(t) / t * K + (1 - np.cos(t)) / t ** 2 * (K @ K)
    np.testing.assert_allclose(so3_exp_map(tiny).numpy()[0], ref, atol=1e-15)


def test_so3_exp_map_gradient_equals_central_differences():
    """The tape's gradient of a loss of so3_exp_map(log_rot) matches finite differences."""
    rng = np.random.default_rng(2)
    v0 = rng.normal(size=(3, 3))
    W = rng.normal(size=(3, 3, 3))

    _check_tape(lambda p: (so3_exp_map(p) * W).sum(), v0, 1e-8)


def test_so3_validators():
    """Shapes are checked at the boundary; the log map refuses a tensor with a gradient."""
    with pytest.raises(ValueError, match="log_rot"):
        so3_exp_map(np.zeros((3,)))
    with pytest.raises(ValueError, match="R"):
        so3_log_map(np.zeros((2, 3)))
    with pytest.raises(TypeError, match="detach"):
        so3_log_map(torch.Parameter(np.eye(3)[None]))


def test_grid_sample_is_bilinear_with_zero_padding():
    """grid_sample: pixel centres return the pixel (align_corners=True: -1, 1 are the corner
    centres; False: their outer edges), a midpoint the mean, outside zero; on a linear image
    bilinear sampling is exact."""
    F = torch.nn.functional
    H, W = 4, 5
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    img = (2.0 * xx + 3.0 * yy)[None, None]  # linear in the pixel coordinates
    # align_corners=True: column c at x = 2 c / (W - 1) - 1
    x = np.array([-1.0, 1.0, 0.1, 2.0])
    y = np.array([-1.0, 1.0, -0.3, 0.0])
    out = F.grid_sample(img, np.stack([x, y], -1)[None, :, None], align_corners=True).numpy()
    c, r = (x + 1) * (W - 1) / 2, (y + 1) * (H - 1) / 2
    np.testing.assert_allclose(out[0, 0, :3, 0], (2 * c + 3 * r)[:3], atol=1e-12)
    assert out[0, 0, 3, 0] == 0.0  # x = 2 is outside: zero padding
    # align_corners=False: column c at x = (2 c + 1) / W - 1
    cc = np.array([0.0, 2.0, 4.0])
    xf = (2 * cc + 1) / W - 1
    out = F.grid_sample(img, np.stack([xf, np.full(3, (2 * 1 + 1) / H - 1)], -1)[None, :, None],
                        align_corners=False).numpy()
    np.testing.assert_allclose(out[0, 0, :, 0], 2 * cc + 3.0, atol=1e-12)
    with pytest.raises(ValueError, match="mode"):
        F.grid_sample(img, np.zeros((1, 1, 1, 2)), mode="nearest")
    with pytest.raises(ValueError, match="padding_mode"):
        F.grid_sample(img, np.zeros((1, 1, 1, 2)), padding_mode="border")
    with pytest.raises(TypeError, match="detach"):
        F.grid_sample(torch.Parameter(img), np.zeros((1, 1, 1, 2)))
    with pytest.raises(ValueError, match="input, grid"):
        F.grid_sample(img[0], np.zeros((1, 1, 1, 2)))


def test_functional_activations_record_gradients():
    """relu, softplus, sigmoid, normalize: values as torch's formulas, gradients as FD."""
    F = torch.nn.functional
    rng = np.random.default_rng(3)
    x0 = rng.normal(size=(4, 3))
    np.testing.assert_allclose(F.relu(x0).numpy(), np.maximum(x0, 0))
    np.testing.assert_allclose(F.softplus(x0, beta=2.0).numpy(), np.log1p(np.exp(2 * x0)) / 2,
                               atol=1e-12)
    np.testing.assert_allclose(F.sigmoid(x0).numpy(), 1 / (1 + np.exp(-x0)), atol=1e-12)
    W = rng.normal(size=(4, 3))

    _check_tape(lambda p: ((F.softplus(p, beta=2.0) + F.normalize(p, dim=-1) + F.relu(p))
                           * W).sum(), x0, 1e-7)


def test_plot_scene_validates_its_input():
    """plot_scene takes {subplot: {trace: structure}} and refuses anything else."""
    from geofit.pytorch3d.vis.plotly_vis import plot_batch_individually, plot_scene

    with pytest.raises(TypeError, match="plots"):
        plot_scene([1, 2])
    with pytest.raises(TypeError, match="Meshes, Pointclouds or cameras"):
        plot_scene({"a": {"b": np.zeros(3)}})
    from geofit.pytorch3d.utils import ico_sphere

    with pytest.raises(ValueError, match="subplot_titles"):
        plot_batch_individually(ico_sphere(0).extend(2), subplot_titles=["one"])
    from geofit.pytorch3d.renderer import FoVPerspectiveCameras, look_at_view_transform

    R, T = look_at_view_transform(2.7, 10.0, [0.0, 90.0])
    fig = plot_scene({"cameras": {"cams": FoVPerspectiveCameras(R=R, T=T)}})
    line = np.stack([fig.data[0].x, fig.data[0].y, fig.data[0].z], 1)
    centre = -np.einsum("nj,nij->ni", T.numpy(), R.numpy())  # camera centres -T R^T
    np.testing.assert_allclose(line[0], centre[0], atol=1e-12)
    assert np.linalg.norm(centre[0]) == pytest.approx(2.7)
