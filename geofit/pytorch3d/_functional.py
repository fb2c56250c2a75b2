"""``torch.nn.functional`` for the tutorials: ``normalize``, ``grid_sample`` and the activations.

Each works on :class:`~.tensor.Tensor` values (or arrays) and records its analytic
vector-Jacobian product on the tape where it has one; ``grid_sample`` samples constant images
(the NeRF tutorial's targets) and refuses an input that requires a gradient.
"""
from __future__ import annotations

import numpy as np

from ..fit.nerf import sample_images_at_xys
from ..nn import layers as _layers
from .tensor import Tensor

__all__ = ["grid_sample", "normalize", "relu", "sigmoid", "softplus"]


def _as_tensor(x) -> Tensor:
    return x if isinstance(x, Tensor) else Tensor(np.asarray(x, np.float64))


def normalize(input, p: float = 2.0, dim: int = 1, eps: float = 1e-12):  # noqa: A002
    """``x / max(|x|_2, eps)`` along ``dim`` (``torch.nn.functional.normalize``, p = 2)."""
    if p != 2:
        raise ValueError(f"p: only the Euclidean norm (p=2) is provided, got {p!r}")
    x = _as_tensor(input)
    a = x.data
    n = np.sqrt((a * a).sum(axis=dim, keepdims=True))
    m = np.maximum(n, eps)
    y = a / m

    def vjp(g):
        # above eps: (g - y (g . y)) / |x|; below: g / eps
        inner = (g * y).sum(axis=dim, keepdims=True)
        return (np.where(n > eps, (g - y * inner) / m, g / m),)

    return Tensor._record(y, [x], vjp)


def grid_sample(input, grid, mode: str = "bilinear", padding_mode: str = "zeros",  # noqa: A002
                align_corners: bool | None = None) -> Tensor:
    """Bilinear samples of ``input`` at normalised ``grid`` points (``torch.nn.functional``).

    Parameters
    ----------
    input : (N, C, H, W) Tensor or array
        Constant images (no gradient is recorded to them).
    grid : (N, H_out, W_out, 2) Tensor or array
        ``x`` (column, -1 left .. 1 right) and ``y`` (row, -1 top .. 1 bottom).
    mode : {"bilinear"}
    padding_mode : {"zeros"}
    align_corners : bool
        True: -1 and 1 are the centres of the corner pixels; False (torch's default): their
        outer edges.

    Returns
    -------
    (N, C, H_out, W_out) Tensor
        Zero outside the image, as torch's ``padding_mode="zeros"``.
    """
    if mode != "bilinear":
        raise ValueError(f"mode: only 'bilinear' is provided, got {mode!r}")
    if padding_mode != "zeros":
        raise ValueError(f"padding_mode: only 'zeros' is provided, got {padding_mode!r}")
    for name, t in (("input", input), ("grid", grid)):
        if isinstance(t, Tensor) and t.requires_grad:
            raise TypeError(f"grid_sample: {name} requires a gradient, which the tape does not "
                            f"record here; pass {name}.detach()")
    im = np.asarray(getattr(input, "data", input), np.float64)
    g = np.asarray(getattr(grid, "data", grid), np.float64)
    if im.ndim != 4 or g.ndim != 4 or g.shape[-1] != 2 or g.shape[0] != im.shape[0]:
        raise ValueError(f"input, grid: expected (N, C, H, W) and (N, H_out, W_out, 2) with the "
                         f"same N, got {im.shape} and {g.shape}")
    H, W = im.shape[2:]
    x, y = g[..., 0], g[..., 1]
    if not align_corners:  # pixel edges at -1, 1: the same points in align_corners=True terms
        x = (((x + 1.0) * W - 1.0) / 2.0) * 2.0 / max(W - 1, 1) - 1.0
        y = (((y + 1.0) * H - 1.0) / 2.0) * 2.0 / max(H - 1, 1) - 1.0
    # geofit's sampler takes NDC points (+X left, +Y up): the grid's x, y negated
    out = sample_images_at_xys(im.transpose(0, 2, 3, 1), -np.stack([x, y], axis=-1))
    return Tensor(out.transpose(0, 3, 1, 2))


def _activation(layer, x) -> Tensor:
    x = _as_tensor(x)
    y, cache = layer.forward(x.data)
    return Tensor._record(y, [x], lambda g: (layer.backward(cache, g)[0],))


def relu(input) -> Tensor:  # noqa: A002
    """``max(x, 0)``."""
    return _activation(_layers.ReLU(dtype=np.float64), input)


def sigmoid(input) -> Tensor:  # noqa: A002
    """``1 / (1 + exp(-x))``."""
    return _as_tensor(input).sigmoid()


def softplus(input, beta: float = 1.0, threshold: float = 20.0) -> Tensor:  # noqa: A002
    """``log(1 + exp(beta x)) / beta``, linear above ``beta x > threshold``."""
    return _activation(_layers.Softplus(beta, threshold, dtype=np.float64), input)
