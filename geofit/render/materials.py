"""Surface materials for Phong shading (PyTorch3D's ``Materials``)."""
from __future__ import annotations

import numpy as np

from .._validate import as_array
from .lighting import _batched, _broadcast

__all__ = ["Materials"]


class Materials:
    """Reflectance of a surface, one material per view of the batch.

    The shaded colour is ``(ambient_color * La + diffuse_color * D) * texel +
    specular_color * S`` where ``La`` is the light's ambient colour and ``D``, ``S`` are the
    light's diffuse and specular terms (see :mod:`geofit.render.lighting`).

    Parameters
    ----------
    ambient_color : (N, 3) or (3,) float64
        Default (1, 1, 1).
    diffuse_color : (N, 3) or (3,) float64
        Default (1, 1, 1).
    specular_color : (N, 3) or (3,) float64
        Default (1, 1, 1).
    shininess : float or (N,) float64
        Phong exponent, >= 0; default 64.

    Notes
    -----
    Every parameter has 1 or ``N`` entries and broadcasts to ``N``.

    Examples
    --------
    >>> Materials(specular_color=[[0.0, 1.0, 0.0]], shininess=10.0).shininess
    array([10.])
    """

    _PARAMS = ("ambient_color", "diffuse_color", "specular_color", "shininess")

    def __init__(self, ambient_color=((1.0, 1.0, 1.0),), diffuse_color=((1.0, 1.0, 1.0),),
                 specular_color=((1.0, 1.0, 1.0),), shininess=64.0):
        s = as_array(shininess, "shininess")
        if s.ndim == 0:
            s = s.reshape(1)
        if s.ndim != 1 or s.shape[0] == 0:
            raise ValueError(f"shininess: expected a number or shape (n,), got {s.shape}")
        if np.any(s < 0):
            raise ValueError(f"shininess: expected values >= 0, got minimum {float(s.min())}")
        b = _broadcast(ambient_color=_batched(ambient_color, "ambient_color", (3,)),
                       diffuse_color=_batched(diffuse_color, "diffuse_color", (3,)),
                       specular_color=_batched(specular_color, "specular_color", (3,)),
                       shininess=s)
        for k, v in b.items():
            setattr(self, k, v)

    def __setattr__(self, name, value):
        """Assigning a parameter validates and broadcasts it as the constructor does."""
        if name in self._PARAMS and all(k in self.__dict__ for k in self._PARAMS):
            params = {k: self.__dict__[k] for k in self._PARAMS}
            params[name] = value
            self.__dict__.update(Materials(**params).__dict__)
        else:
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return self.ambient_color.shape[0]

    def __repr__(self) -> str:
        return f"Materials(N={len(self)}, shininess={self.shininess.tolist()})"

    def __getitem__(self, index) -> Materials:
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return Materials(**{k: getattr(self, k)[index] for k in self._PARAMS})

    def extend(self, n: int) -> Materials:
        """Repeat each material ``n`` times."""
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
            raise ValueError(f"n: expected an integer >= 1, got {n!r}")
        return Materials(**{k: np.repeat(getattr(self, k), int(n), axis=0)
                            for k in self._PARAMS})

    def clone(self) -> Materials:
        return Materials(**{k: getattr(self, k) for k in self._PARAMS})
