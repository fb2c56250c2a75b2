"""Lights with PyTorch3D's formulas and defaults: point, directional and ambient.

A light object holds a *batch* of ``N`` lights, one per rendered view (every parameter has a
leading axis of size 1 or ``N`` and broadcasts, as PyTorch3D's ``TensorProperties``). Shading
works on flat arrays of surface points: ``points (k, 3)`` and ``normals (k, 3)`` with an optional
``batch_idx (k,)`` saying which view (and therefore which light of the batch) each point belongs
to.

The formulas (``pytorch3d/renderer/lighting.py``), with ``normalize(x) = x / max(|x|, 1e-6)``:

- ``diffuse = Ld * max(0, n . l)`` with ``n = normalize(normal)``, ``l = normalize(direction)``;
- ``specular = Ls * max(0, r . v) ** shininess * [n . l > 0]`` with ``r = -l + 2 (n . l) n`` and
  ``v = normalize(camera_position - point)``;
- no attenuation with distance, no shadows, no two-sided lighting.

The 1e-6 normalisation epsilon also covers a light placed exactly at a surface point (a zero
light vector): that point gets the ambient term only, never NaN.
"""
from __future__ import annotations

import numpy as np

from .._validate import as_array, shape_str

__all__ = ["AmbientLights", "DirectionalLights", "PointLights", "diffuse", "specular"]

_EPS = 1e-6  # torch.nn.functional.normalize(eps=1e-6), as in pytorch3d.renderer.lighting


def _batched(x, name: str, item: tuple) -> np.ndarray:
    """``item``-shaped or ``(n, *item)`` input as a finite ``(n, *item)`` float64 array."""
    a = as_array(x, name)
    if a.shape == item:
        a = a[None]
    if a.ndim != len(item) + 1 or a.shape[1:] != item or a.shape[0] == 0:
        raise ValueError(f"{name}: expected shape {shape_str((None,) + item)} or "
                         f"{shape_str(item)}, got {a.shape}")
    return a


def _broadcast(**arrays: np.ndarray) -> dict:
    """Broadcast the leading axes (1 or N) of every array to N."""
    sizes = {k: v.shape[0] for k, v in arrays.items()}
    n = max(sizes.values())
    if any(s not in (1, n) for s in sizes.values()):
        listing = ", ".join(f"{k} has {s}" for k, s in sizes.items())
        raise ValueError(f"mismatched batch sizes: every parameter needs 1 or N = {n} entries, "
                         f"got {listing}")
    out = {}
    for k, v in arrays.items():
        v = np.array(np.broadcast_to(v, (n,) + v.shape[1:]), dtype=np.float64)
        v.flags.writeable = False
        out[k] = v
    return out


def per_point(param: np.ndarray, batch_idx: np.ndarray | None, dtype=np.float32) -> np.ndarray:
    """Gather a batched ``(N, C)`` parameter for points with batch indices ``batch_idx (k,)``.

    Returns a ``(1, C)`` array (ready to broadcast against ``(k, C)``) when ``N == 1`` or
    ``batch_idx`` is None, else ``(k, C)``.
    """
    if batch_idx is None or param.shape[0] == 1:
        return param[:1].astype(dtype, copy=False)
    return param.astype(dtype, copy=False)[batch_idx]


def per_point_t(param: np.ndarray, batch_idx: np.ndarray | None, dtype=np.float32) -> np.ndarray:
    """:func:`per_point` in component-first layout: ``(C, 1)`` or ``(C, k)``."""
    if batch_idx is None or param.shape[0] == 1:
        return np.ascontiguousarray(param[:1].T, dtype=dtype)
    return np.ascontiguousarray(param.T, dtype=dtype)[:, batch_idx]


# The formulas work on component-first arrays ``(3, k)`` (fast contiguous rows); the public
# functions and methods take and return ``(k, 3)``.


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _normalize(x: np.ndarray) -> np.ndarray:
    """``x / max(|x|, 1e-6)`` over axis 0."""
    return x / np.maximum(np.sqrt(_dot(x, x)), x.dtype.type(_EPS))


def _diffuse(n, color, direction):
    n = _normalize(n)
    l = _normalize(direction)
    return color * np.maximum(_dot(n, l), 0)


def _specular(points, n, direction, camera_position, shininess, color):
    n = _normalize(n)
    l = _normalize(direction)
    cos = _dot(n, l)
    v = _normalize(camera_position - points)
    r = (2 * cos) * n - l
    alpha = np.maximum(_dot(v, r), 0) * (cos > 0)
    return color * np.power(alpha, shininess)


def _phong_terms(n, p, direction, camera_position, shininess, ld, ls, unit_normals=False):
    """Diffuse and specular terms together (the light direction normalised once)."""
    if not unit_normals:
        n = _normalize(n)
    l = _normalize(direction)
    cos = _dot(n, l)
    dif = ld * np.maximum(cos, 0)
    v = _normalize(camera_position - p)
    r = (2 * cos) * n - l
    alpha = np.maximum(_dot(v, r), 0) * (cos > 0)
    return dif, ls * np.power(alpha, shininess)


def diffuse(normals: np.ndarray, color: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Lambert's term ``color * max(0, n . l)`` (PyTorch3D's ``diffuse``).

    Parameters
    ----------
    normals : (k, 3) float
        Surface normals (need not be unit length; normalised with eps 1e-6).
    color : (k, 3) or (1, 3) float
        Diffuse colour of the light at each point.
    direction : (k, 3) or (1, 3) float
        Direction from the surface towards the light (need not be unit length).

    Returns
    -------
    (k, 3) float, same dtype as ``normals``.
    """
    n = np.asarray(normals)
    return _diffuse(n.T, np.asarray(color, n.dtype).T, np.asarray(direction, n.dtype).T).T


def specular(points: np.ndarray, normals: np.ndarray, direction: np.ndarray,
             camera_position: np.ndarray, shininess, color: np.ndarray) -> np.ndarray:
    """Phong's specular term (PyTorch3D's ``specular``).

    ``color * max(0, r . v) ** shininess`` where ``n . l > 0`` (zero elsewhere), with
    ``r = -l + 2 (n . l) n`` and ``v = normalize(camera_position - points)``.

    Parameters
    ----------
    points : (k, 3) float
        Surface points (world coordinates).
    normals : (k, 3) float
        Surface normals (normalised with eps 1e-6).
    direction : (k, 3) or (1, 3) float
        Direction from the surface towards the light.
    camera_position : (k, 3) or (1, 3) float
        Camera centre seen from each point.
    shininess : float, (k,) or (1,) float
        Phong exponent.
    color : (k, 3) or (1, 3) float
        Specular colour of the light.

    Returns
    -------
    (k, 3) float
    """
    n = np.asarray(normals)
    dt = n.dtype
    return _specular(np.asarray(points, dt).T, n.T, np.asarray(direction, dt).T,
                     np.asarray(camera_position, dt).T, np.asarray(shininess, dt),
                     np.asarray(color, dt).T).T


_COLORS = ("ambient_color", "diffuse_color", "specular_color")


class _Lights:
    """Shared batch machinery of the light classes."""

    _PARAMS: tuple[str, ...] = ()

    def __len__(self) -> int:
        return getattr(self, self._PARAMS[0]).shape[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(N={len(self)})"

    def __setattr__(self, name, value):
        """Assigning a parameter validates and broadcasts it as the constructor does."""
        if name in self._PARAMS and all(k in self.__dict__ for k in self._PARAMS):
            params = {k: self.__dict__[k] for k in self._PARAMS}
            params[name] = _batched(value, name, (3,))
            self.__dict__.update(_broadcast(**params))
        else:
            object.__setattr__(self, name, value)

    def _set(self, **params) -> None:
        """Validate each (N, 3) or (3,) parameter and broadcast the batch to one N."""
        batched = {k: _batched(v, k, (3,)) for k, v in params.items()}
        for k, v in _broadcast(**batched).items():
            setattr(self, k, v)

    def _with(self, **params):
        new = type(self).__new__(type(self))
        for k, v in _broadcast(**params).items():
            setattr(new, k, v)
        return new

    def __getitem__(self, index) -> _Lights:
        """The lights at ``index`` (int, slice or index array), as a batch."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return self._with(**{k: getattr(self, k)[index] for k in self._PARAMS})

    def extend(self, n: int) -> _Lights:
        """Repeat each light ``n`` times (as ``Meshes.extend``)."""
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
            raise ValueError(f"n: expected an integer >= 1, got {n!r}")
        return self._with(**{k: np.repeat(getattr(self, k), int(n), axis=0)
                             for k in self._PARAMS})

    def clone(self) -> _Lights:
        return self._with(**{k: getattr(self, k) for k in self._PARAMS})

    # Subclasses define the light direction seen from each point (component-first).
    def _light_vector(self, p: np.ndarray, batch_idx):  # pragma: no cover - abstract
        raise NotImplementedError

    def light_vector(self, points, batch_idx=None) -> tuple[np.ndarray, np.ndarray]:
        """Vector from each point towards the light and the distance to it.

        Parameters
        ----------
        points : (k, 3) float
            Surface points, world coordinates.
        batch_idx : (k,) int64, optional
            View of each point; needed when the batch holds more than one light.

        Returns
        -------
        direction : (k, 3) float
            Towards the light, not normalised (``location - point`` for point lights, the
            light's direction for directional ones, zero for ambient light).
        distance : (k,) float
            Distance to the light (the shadow-ray extent): inf for directional lights.
        """
        p = np.asarray(points)
        d, dist = self._light_vector(p.T, batch_idx)
        return np.ascontiguousarray(np.broadcast_to(d, p.T.shape).T), dist

    def _diffuse_t(self, n, p, batch_idx):
        d, _ = self._light_vector(p, batch_idx)
        return _diffuse(n, per_point_t(self.diffuse_color, batch_idx, n.dtype), d)

    def _terms_t(self, n, p, camera_position, shininess, batch_idx, unit_normals=False):
        """Component-first (diffuse, specular), each ``(3, k)``."""
        d, _ = self._light_vector(p, batch_idx)
        return _phong_terms(n, p, d, camera_position, shininess,
                            per_point_t(self.diffuse_color, batch_idx, n.dtype),
                            per_point_t(self.specular_color, batch_idx, n.dtype), unit_normals)

    def _specular_t(self, n, p, camera_position, shininess, batch_idx):
        d, _ = self._light_vector(p, batch_idx)
        return _specular(p, n, d, camera_position, shininess,
                         per_point_t(self.specular_color, batch_idx, n.dtype))

    def diffuse(self, normals, points, batch_idx=None) -> np.ndarray:
        """Diffuse light reflected at each point.

        Parameters
        ----------
        normals, points : (k, 3) float
            Surface normals and points (world coordinates).
        batch_idx : (k,) int64, optional
            View of each point, as in :meth:`light_vector`.

        Returns
        -------
        (k, 3) float, the dtype of ``normals``.
        """
        n = np.asarray(normals)
        return self._diffuse_t(n.T, np.asarray(points, n.dtype).T, batch_idx).T

    def specular(self, normals, points, camera_position, shininess, batch_idx=None) -> np.ndarray:
        """Specular light reflected towards the camera at each point.

        Parameters
        ----------
        normals, points : (k, 3) float
            Surface normals and points.
        camera_position : (k, 3) or (1, 3) float
            Camera centre for each point.
        shininess : float, (k,) or (1,) float
            Phong exponent for each point.
        batch_idx : (k,) int64, optional
            View of each point.

        Returns
        -------
        (k, 3) float
        """
        n = np.asarray(normals)
        dt = n.dtype
        return self._specular_t(n.T, np.asarray(points, dt).T,
                                np.asarray(camera_position, dt).T,
                                np.asarray(shininess, dt), batch_idx).T


class _PhongLights(_Lights):
    """Lights with ambient, diffuse and specular colours and one geometric parameter, the last
    name in ``_PARAMS`` (``location`` or ``direction``, default (0, 1, 0)); PyTorch3D's
    defaults for the colours."""

    def __init__(self, ambient_color=((0.5, 0.5, 0.5),), diffuse_color=((0.3, 0.3, 0.3),),
                 specular_color=((0.2, 0.2, 0.2),), **geometry):
        name = self._PARAMS[-1]
        unknown = sorted(set(geometry) - {name})
        if unknown:
            raise TypeError(f"{type(self).__name__}: unexpected argument {unknown[0]!r}")
        self._set(ambient_color=ambient_color, diffuse_color=diffuse_color,
                  specular_color=specular_color, **{name: geometry.get(name, ((0.0, 1.0, 0.0),))})


class PointLights(_PhongLights):
    """Point lights (PyTorch3D's ``PointLights``), one per view of the batch.

    Parameters
    ----------
    ambient_color : (N, 3) or (3,) float64
        Ambient colour; default (0.5, 0.5, 0.5).
    diffuse_color : (N, 3) or (3,) float64
        Diffuse colour; default (0.3, 0.3, 0.3).
    specular_color : (N, 3) or (3,) float64
        Specular colour; default (0.2, 0.2, 0.2).

    Other Parameters
    ----------------
    location : (N, 3) or (3,) float64
        Light positions in world coordinates; default (0, 1, 0). Keyword only.

    Notes
    -----
    Every parameter has 1 or ``N`` rows and broadcasts to ``N``.

    Examples
    --------
    >>> lights = PointLights(location=[[0.0, 0.0, -3.0]])
    >>> lights.diffuse(np.array([[0.0, 0.0, -1.0]]), np.zeros((1, 3))).round(6)
    array([[0.3, 0.3, 0.3]])
    """

    _PARAMS = _COLORS + ("location",)

    def _light_vector(self, p, batch_idx):
        d = per_point_t(self.location, batch_idx, p.dtype) - p
        return d, np.sqrt(_dot(d, d))


class DirectionalLights(_PhongLights):
    """Directional lights (PyTorch3D's ``DirectionalLights``), one per view of the batch.

    Parameters
    ----------
    ambient_color, diffuse_color, specular_color : (N, 3) or (3,) float64
        As in :class:`PointLights` (defaults 0.5, 0.3, 0.2 grey).

    Other Parameters
    ----------------
    direction : (N, 3) or (3,) float64
        Direction *towards* the light (from the surface), world coordinates; default (0, 1, 0).
        Keyword only.
    """

    _PARAMS = _COLORS + ("direction",)

    def _light_vector(self, p, batch_idx):
        d = per_point_t(self.direction, batch_idx, p.dtype)
        return d, np.full(p.shape[1], np.inf, dtype=p.dtype)


class AmbientLights(_Lights):
    """Ambient light only (PyTorch3D's ``AmbientLights``): no diffuse or specular part.

    Parameters
    ----------
    ambient_color : (N, 3) or (3,) float64
        Default white (1, 1, 1), which with the default materials shows the raw texture.
    """

    _PARAMS = _COLORS

    def __init__(self, ambient_color=((1.0, 1.0, 1.0),)):
        a = _batched(ambient_color, "ambient_color", (3,))
        b = _broadcast(ambient_color=a, diffuse_color=np.zeros_like(a),
                       specular_color=np.zeros_like(a))
        for k, v in b.items():
            setattr(self, k, v)

    def _light_vector(self, p, batch_idx):
        return np.zeros_like(p), np.zeros(p.shape[1], dtype=p.dtype)

    def _diffuse_t(self, n, p, batch_idx):
        return np.zeros_like(n)

    def _terms_t(self, n, p, camera_position, shininess, batch_idx, unit_normals=False):
        return np.zeros_like(n), np.zeros_like(n)

    def _specular_t(self, n, p, camera_position, shininess, batch_idx):
        return np.zeros_like(n)
