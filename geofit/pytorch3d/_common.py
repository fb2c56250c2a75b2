"""Helpers shared by the geofit.pytorch3d modules: array conversion, the ``device=`` shim, packed
<-> padded tensors on the tape, and the module ``__getattr__`` for PyTorch3D names this layer does
not provide (each returns a placeholder that raises, with what to use instead, when used)."""
from __future__ import annotations

import dis
import sys

import numpy as np

from .tensor import Tensor


def np_(x, dtype=None):
    """The numpy value of ``x`` (a Tensor, a list of them, or array_like)."""
    if isinstance(x, Tensor):
        x = x.data
    elif isinstance(x, (list, tuple)) and any(isinstance(v, Tensor) for v in x):
        x = [np_(v) for v in x]
    return np.asarray(x, dtype=dtype)


def drop_device(cls):
    """A subclass of geofit's ``cls`` whose constructor accepts and ignores ``device=`` and takes
    Tensors where geofit takes arrays (PyTorch3D's constructors all take ``device``)."""

    def __init__(self, *args, device=None, **kwargs):
        args = [np_(a) if isinstance(a, Tensor) else a for a in args]
        kwargs = {k: (np_(v) if isinstance(v, Tensor) else v) for k, v in kwargs.items()}
        cls.__init__(self, *args, **kwargs)

    def __setattr__(self, name, value):
        # lights.location = torch.tensor([[0.0, 0.0, 1.0]]): store the array geofit expects
        if isinstance(value, Tensor):
            value = np.asarray(value.data, np.float64)
        cls.__setattr__(self, name, value)

    def to(self, *args, **kwargs):
        return self

    ns = {"__init__": __init__, "to": to, "__doc__": cls.__doc__, "__module__": cls.__module__,
          "__qualname__": cls.__qualname__}
    if "__slots__" not in cls.__dict__ and not getattr(cls, "__dataclass_params__", None):
        ns["__setattr__"] = __setattr__
    if not hasattr(cls, "_drop_device_base"):
        ns["_drop_device_base"] = cls
    return type(cls.__name__, (cls,), ns)


_IMPORT_FROM = dis.opmap["IMPORT_FROM"]


def _called_by_from_import(depth: int) -> bool:
    """True when the frame ``depth`` levels up is executing ``from module import name``.

    Python turns an AttributeError raised there into a bare "cannot import name" ImportError;
    raising the ImportError ourselves keeps the hint.
    """
    try:
        f = sys._getframe(depth + 1)
        return f.f_lasti >= 0 and f.f_code.co_code[f.f_lasti] == _IMPORT_FROM
    except (ValueError, IndexError):  # pragma: no cover - no such frame
        return False


class MissingName:
    """A PyTorch3D name that geofit.pytorch3d does not provide: importing it works, using it
    (calling or instantiating it, reading an attribute) raises ``NotImplementedError`` saying
    what to use instead.

    So a tutorial's import cell never fails for a name the code may not reach (the points
    tutorial imports ``PulsarPointsRenderer`` next to the renderers it does use).
    """

    def __init__(self, qualname: str, hint: str):
        self._qualname = qualname
        self._hint = hint

    def _message(self) -> str:
        return f"{self._qualname} is not provided by geofit.pytorch3d: {self._hint}"

    def __call__(self, *args, **kwargs):
        raise NotImplementedError(self._message())

    def __getattr__(self, name: str):
        if name.startswith("_"):  # introspection (IPython, pickle, doctest) must see no attribute
            raise AttributeError(name)
        raise NotImplementedError(self._message())

    def __repr__(self) -> str:
        return f"<not provided: {self._qualname}; {self._hint}>"


def missing_names(module_name: str, hints: dict):
    """A module ``__getattr__`` for PyTorch3D names this layer does not provide.

    A name in ``hints`` (PyTorch3D's name -> what to use instead) returns a
    :class:`MissingName` that raises ``NotImplementedError`` with the hint at first use, so
    ``from module import Name`` succeeds. Any other name raises AttributeError
    (``ImportError`` in ``from module import Name``), pointing at the list of what is provided.
    """

    def __getattr__(name: str):
        if name.startswith("__"):
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        hint = hints.get(name)
        if hint is not None:
            return MissingName(f"{module_name}.{name}", hint)
        msg = (f"{module_name}.{name}: not provided by geofit.pytorch3d, which covers the "
               f"calls of PyTorch3D's six introductory tutorials (docs/pytorch3d.md lists "
               f"them)")
        if _called_by_from_import(1):
            raise ImportError(msg, name=module_name)
        raise AttributeError(msg)

    return __getattr__


def padded_index(counts: np.ndarray):
    """(mesh index, index within the mesh) of every packed row."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    mesh_idx = np.repeat(np.arange(len(counts)), counts)
    local = np.arange(int(counts.sum())) - np.repeat(starts, counts)
    return mesh_idx, local


def to_padded(packed: Tensor, counts: np.ndarray, pad_value: float = 0.0) -> Tensor:
    """Packed (sum n, C) rows to (N, max n, C), recorded on the tape."""
    mi, li = padded_index(counts)
    n_max = int(counts.max()) if len(counts) else 0
    out = np.full((len(counts), n_max) + packed.data.shape[1:], pad_value,
                  dtype=packed.data.dtype)
    out[mi, li] = packed.data
    return Tensor._record(out, (packed,), lambda g: (g[mi, li],))


def from_padded(padded: Tensor, counts: np.ndarray) -> Tensor:
    """(N, max n, C) to packed (sum n, C) rows, recorded (an index into the padded tensor)."""
    mi, li = padded_index(counts)
    return padded[mi, li]
