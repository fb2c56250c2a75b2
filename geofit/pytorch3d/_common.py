"""Helpers shared by the geofit.pytorch3d modules: array conversion, the ``device=`` shim and the
module ``__getattr__`` that names what to use for a PyTorch3D name this layer does not provide."""
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


def missing_names(module_name: str, hints: dict):
    """A module ``__getattr__`` for PyTorch3D names this layer does not provide.

    ``module.Name`` raises AttributeError and ``from module import Name`` raises ImportError,
    both saying what to use instead (``hints[name]``), or pointing at the README table.
    """

    def __getattr__(name: str):
        if name.startswith("__"):
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        hint = hints.get(name)
        if hint is None:
            msg = (f"{module_name}.{name}: not provided by geofit.pytorch3d, which covers the "
                   f"calls of PyTorch3D's six introductory tutorials (README: 'Coming from "
                   f"PyTorch3D')")
        else:
            msg = f"{module_name}.{name} is not provided by geofit.pytorch3d: {hint}"
        if _called_by_from_import(1):
            raise ImportError(msg, name=module_name)
        raise AttributeError(msg)

    return __getattr__
