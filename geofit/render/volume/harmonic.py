"""Harmonic (Fourier-feature) embeddings of points and directions, as PyTorch3D computes them.

Two variants, because PyTorch3D has two:

* :class:`HarmonicEmbedding` -- the library module ``pytorch3d.renderer.HarmonicEmbedding``
  (options ``n_harmonic_functions``, ``omega_0``, ``logspace``, ``append_input``). Its frequency
  buffer is float32, and its "cos" half is ``sin(theta + fl32(pi/2))``, not ``cos(theta)``:
  ``fl32(pi/2) = 1.5707963705062866`` exceeds pi/2 by 4.37e-8, so the column equals
  ``cos(theta) - 4.37e-8 sin(theta)``, and once ``|theta|`` is so large that adding pi/2 is lost
  to rounding the column equals the sin column. geofit reproduces this by default so that
  embeddings match PyTorch3D's bit for bit in float64 and to an ulp in float32;
  ``exact_cos=True`` gives the true cosine.
* :class:`TutorialHarmonicEmbedding` -- the module the NeRF tutorial defines for itself:
  frequencies ``omega0 * 2^k`` (``omega0 = 0.1``, 60 of them, a float32 buffer), output
  ``[sin(x f), cos(x f)]`` with a true cosine and no appended input (dimension 360 for 3-D input).

Both order the columns per input dimension first, then per frequency: column ``d * n + k`` of a
half holds input dimension ``d`` at frequency ``k``.

In float32 the product ``x * f`` carries a rounding error of about ``|x f| 2^-24`` radians; with
the tutorial's frequencies (up to ``0.1 * 2^59``) that error exceeds a full turn from ``k`` of
about 30, so those columns are effectively arbitrary. geofit's scene-sized NeRF uses 6 to 10
frequencies, where float32 is exact enough.
"""
from __future__ import annotations

import numpy as np

from ..._validate import check_positive

__all__ = ["HALF_PI_F32", "HarmonicEmbedding", "TutorialHarmonicEmbedding"]

#: ``float32(pi / 2)`` as PyTorch3D adds it for its "cos" half.
HALF_PI_F32 = float(np.float32(np.pi / 2))


def _as_input(x, name: str = "x") -> np.ndarray:
    x = np.asarray(x)
    if x.ndim < 1 or x.shape[-1] < 1:
        raise ValueError(f"{name}: expected shape (..., d) with d >= 1, got {tuple(x.shape)}")
    if x.dtype not in (np.float32, np.float64):
        if x.dtype.kind not in "iub":
            raise ValueError(f"{name}: expected real numbers, got dtype {x.dtype}")
        x = x.astype(np.float64)
    if x.size and not np.all(np.isfinite(x)):
        raise ValueError(f"{name}: expected finite values, got NaN or inf entries")
    return x


def _n_functions(n) -> int:
    try:
        n = int(n)
    except (TypeError, ValueError):
        raise ValueError(f"n_harmonic_functions: expected an integer >= 1, got {n!r}") from None
    if n < 1:
        raise ValueError(f"n_harmonic_functions: expected an integer >= 1, got {n}")
    return n


def _linspace_f32(start: float, end: float, n: int) -> np.ndarray:
    """``torch.linspace(start, end, n, dtype=float32)`` on the CPU (symmetric two-sided fill)."""
    out = np.empty(n, dtype=np.float32)
    if n == 1:
        out[0] = start
        return out
    start32, end32 = np.float32(start), np.float32(end)
    step = np.float32((end32 - start32) / np.float32(n - 1))
    half = n // 2
    i = np.arange(n)
    lo = i < half
    out[lo] = start32 + step * i[lo].astype(np.float32)
    out[~lo] = end32 - step * (n - 1 - i[~lo]).astype(np.float32)
    return out


class HarmonicEmbedding:
    """PyTorch3D's ``HarmonicEmbedding``: ``[sin(x f), "cos"(x f), x]``.

    Parameters
    ----------
    n_harmonic_functions : int
        Number of frequencies ``n`` (>= 1).
    omega_0 : float
        Base frequency (> 0).
    logspace : bool
        Frequencies ``omega_0 2^k`` for ``k = 0..n-1`` (True) or ``omega_0 * linspace(1,
        2^(n-1), n)`` (False), both computed in float32 as PyTorch3D does.
    append_input : bool
        Append the input coordinates after the harmonics.
    exact_cos : bool
        False (default): PyTorch3D's ``sin(theta + fl32(pi/2))`` for the second half; True: the
        true ``cos(theta)``.

    Attributes
    ----------
    frequencies : (n,) float32
        The frequency buffer.

    Examples
    --------
    >>> emb = HarmonicEmbedding()
    >>> emb(np.zeros((5, 3))).shape, emb.output_dim(3)
    ((5, 39), 39)
    """

    def __init__(self, n_harmonic_functions: int = 6, omega_0: float = 1.0,
                 logspace: bool = True, append_input: bool = True, *, exact_cos: bool = False):
        n = _n_functions(n_harmonic_functions)
        omega_0 = check_positive(omega_0, "omega_0")
        if logspace:
            base = np.float32(2.0) ** np.arange(n, dtype=np.float32)
        else:
            base = _linspace_f32(1.0, 2.0 ** (n - 1), n)
        self.frequencies = (base * np.float32(omega_0)).astype(np.float32)
        self.n_harmonic_functions = n
        self.omega_0 = omega_0
        self.logspace = bool(logspace)
        self.append_input = bool(append_input)
        self.exact_cos = bool(exact_cos)

    def output_dim(self, input_dims: int = 3) -> int:
        """Number of output columns for ``input_dims`` input coordinates."""
        return input_dims * (2 * self.n_harmonic_functions + int(self.append_input))

    def __repr__(self) -> str:
        return (f"HarmonicEmbedding(n_harmonic_functions={self.n_harmonic_functions}, "
                f"omega_0={self.omega_0:g}, logspace={self.logspace}, "
                f"append_input={self.append_input}, exact_cos={self.exact_cos})")

    def __call__(self, x) -> np.ndarray:
        """Embed ``x (..., d)`` into ``(..., d (2 n + append_input))`` in the input's dtype.

        Parameters
        ----------
        x : (..., d) float32 or float64
            Points or directions (integers are converted to float64).

        Returns
        -------
        embedding : (..., d (2 n + append_input))
            ``[sin(x_d f_k) over d, k] + [sin(x_d f_k + fl32(pi/2)) (or cos) over d, k] + [x]``.
        """
        x = _as_input(x)
        return self._embed(x)

    def _embed(self, x: np.ndarray) -> np.ndarray:
        f = self.frequencies.astype(x.dtype)
        theta = (x[..., None] * f).reshape(*x.shape[:-1], -1)
        parts = [np.sin(theta)]
        if self.exact_cos:
            parts.append(np.cos(theta))
        else:
            parts.append(np.sin(theta + x.dtype.type(HALF_PI_F32)))
        if self.append_input:
            parts.append(x)
        return np.concatenate(parts, axis=-1)


class TutorialHarmonicEmbedding:
    """The NeRF tutorial's own ``HarmonicEmbedding``: ``[sin(x f), cos(x f)]``.

    Parameters
    ----------
    n_harmonic_functions : int
        Number of frequencies (the tutorial uses 60).
    omega0 : float
        Base frequency (the tutorial uses 0.1); ``f_k = fl32(omega0) 2^k``, a float32 buffer.
    buffer_dtype : float32 or float64
        dtype of the frequency buffer: float32 as in the tutorial, float64 for the correctly
        rounded ``omega0 2^k``.

    Examples
    --------
    >>> emb = TutorialHarmonicEmbedding()
    >>> emb.output_dim(3), emb(np.zeros((2, 3), np.float32)).dtype
    (360, dtype('float32'))
    """

    append_input = False

    def __init__(self, n_harmonic_functions: int = 60, omega0: float = 0.1, *,
                 buffer_dtype=np.float32):
        n = _n_functions(n_harmonic_functions)
        omega0 = check_positive(omega0, "omega0")
        dt = np.dtype(buffer_dtype)
        if dt not in (np.float32, np.float64):
            raise ValueError(f"buffer_dtype: expected float32 or float64, got {dt}")
        self.frequencies = dt.type(omega0) * dt.type(2.0) ** np.arange(n, dtype=dt)
        self.n_harmonic_functions = n
        self.omega0 = omega0

    def output_dim(self, input_dims: int = 3) -> int:
        """Number of output columns for ``input_dims`` input coordinates."""
        return input_dims * 2 * self.n_harmonic_functions

    def __repr__(self) -> str:
        return (f"TutorialHarmonicEmbedding(n_harmonic_functions={self.n_harmonic_functions}, "
                f"omega0={self.omega0:g})")

    def __call__(self, x) -> np.ndarray:
        """Embed ``x (..., d)`` into ``(..., 2 d n)`` in the input's dtype (float32 as in the
        tutorial: the product ``x f`` is rounded to float32 before sin and cos)."""
        x = _as_input(x)
        return self._embed(x)

    def _embed(self, x: np.ndarray) -> np.ndarray:
        theta = (x[..., None] * self.frequencies.astype(x.dtype)).reshape(*x.shape[:-1], -1)
        return np.concatenate([np.sin(theta), np.cos(theta)], axis=-1)
