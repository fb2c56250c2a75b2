"""Input helpers shared by the camera modules (public entry points validate with these, then
trust their arrays)."""
from __future__ import annotations

import numpy as np

from .._validate import as_array, check_positive, shape_str

# torch.nn.functional.normalize(eps=1e-5) and the isclose(x, 0, atol=5e-3) fallback of
# pytorch3d.renderer.cameras.look_at_rotation.
_NORMALIZE_EPS = 1e-5
_X_AXIS_FALLBACK_ATOL = 5e-3
# |cos(elev)| below this counts as a pole: elev is +-90 degrees to within float32 resolution.
_POLE_COS = 1e-7
# Largest max|R R^T - I| accepted for a camera rotation.
_ROTATION_TOL = 1e-4



def _batch_scalar(x, name: str) -> np.ndarray:
    """A scalar or ``(n,)`` array as a finite ``(n,)`` float64 array with ``n >= 1``."""
    a = as_array(x, name)
    if a.ndim == 0:
        a = a.reshape(1)
    if a.ndim != 1 or a.shape[0] == 0:
        raise ValueError(f"{name}: expected a scalar or shape (n,) with n >= 1, got {a.shape}")
    return a


def _batch_items(x, name: str, item: tuple) -> np.ndarray:
    """An ``item``-shaped or ``(n, *item)`` array as a finite ``(n, *item)`` float64 array."""
    a = as_array(x, name)
    if a.shape == item:
        a = a[None]
    if a.ndim != len(item) + 1 or a.shape[1:] != item or a.shape[0] == 0:
        raise ValueError(
            f"{name}: expected shape {shape_str((None,) + item)} or {shape_str(item)}, "
            f"got {a.shape}"
        )
    return a


def _broadcast_batch(**arrays: np.ndarray) -> dict:
    """Broadcast the leading (batch) axis of every array to the common size ``N``.

    Each array must have batch size 1 or ``N``, as in PyTorch3D's
    ``convert_to_tensors_and_broadcast``.
    """
    sizes = {k: v.shape[0] for k, v in arrays.items()}
    n = max(sizes.values())
    if any(s not in (1, n) for s in sizes.values()):
        listing = ", ".join(f"{k} has {s}" for k, s in sizes.items())
        raise ValueError(
            f"mismatched batch sizes: every argument needs 1 or N = {n} entries, got {listing}"
        )
    return {k: np.ascontiguousarray(np.broadcast_to(v, (n,) + v.shape[1:])) for k, v in
            arrays.items()}


def _image_size(image_size, name: str = "image_size") -> tuple[int, int]:
    """One ``(H, W)`` pair of positive integers."""
    a = as_array(image_size, name, dtype=np.int64)
    if a.shape == (1, 2):
        a = a[0]
    if a.shape != (2,):
        raise ValueError(f"{name}: expected (H, W), shape (2,), got shape {a.shape}")
    if np.any(a < 1):
        raise ValueError(f"{name}: expected positive (H, W), got {tuple(int(v) for v in a)}")
    return int(a[0]), int(a[1])


def _image_sizes(image_size, name: str = "image_size") -> np.ndarray:
    """``(H, W)`` or ``(n, 2)`` positive integers as an ``(n, 2)`` int64 array."""
    a = as_array(image_size, name, dtype=np.int64)
    if a.shape == (2,):
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] == 0:
        raise ValueError(f"{name}: expected (H, W), shape (2,) or (n, 2), got shape {a.shape}")
    if np.any(a < 1):
        raise ValueError(f"{name}: expected positive (H, W) sizes, got minimum {int(a.min())}")
    return a


def _check_rotations(R: np.ndarray, name: str) -> None:
    """Raise unless every ``R[n]`` is orthonormal with determinant +1 (to ``_ROTATION_TOL``)."""
    err = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((err > _ROTATION_TOL) | (np.abs(det - 1.0) > _ROTATION_TOL))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name}: expected rotation matrices (orthonormal, det +1); {bad.size} of {len(R)} "
            f"are not, e.g. R[{i}] has max|R R^T - I| = {err[i]:.3g} and det {det[i]:.6g}"
        )


def _check_bool(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def _normalize(v: np.ndarray) -> np.ndarray:
    """``torch.nn.functional.normalize(v, dim=-1, eps=1e-5)``: ``v / max(|v|, eps)``."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(norm, _NORMALIZE_EPS)


def _homogeneous_divide(h: np.ndarray, eps) -> np.ndarray:
    """``h[..., :3] / h[..., 3:]``, the divisor clamped to ``|w| >= eps`` (sign kept) if given."""
    w = h[..., 3:]
    if eps is not None:
        eps = check_positive(eps, "eps", strict=False)
        sign = np.sign(w) + (w == 0.0)
        w = sign * np.maximum(np.abs(w), eps)
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[..., :3] / w
