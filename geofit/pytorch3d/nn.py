"""``torch.nn`` pieces the tutorials use: ``Parameter`` and a ``Module`` base that collects them.

:class:`Module` does what the volume tutorial's ``VolumeModel(torch.nn.Module)`` needs:
``parameters()`` finds the :class:`~.tensor.Parameter` attributes (also of sub-modules), calling
the module runs ``forward``, ``.to(device)`` returns it. It is *not* a layer library: the NeRF
tutorial's ``torch.nn.Linear`` / ``Softplus`` network is not emulated (geofit's
geofit's ``NeuralRadianceField`` (:mod:`geofit.render`) is that network with its analytic backward).
"""
from __future__ import annotations

from ._common import missing_names
from .tensor import Parameter

__all__ = ["Module", "Parameter"]


class Module:
    """Base class: ``parameters()``, ``named_parameters()``, ``__call__ -> forward``, ``to``.

    Examples
    --------
    >>> import numpy as np
    >>> class Scale(Module):
    ...     def __init__(self):
    ...         super().__init__()
    ...         self.w = Parameter(np.ones(3))
    ...     def forward(self, x):
    ...         return x * self.w
    >>> m = Scale()
    >>> [tuple(p.shape) for p in m.parameters()], m(np.arange(3.0)).sum().item()
    ([(3,)], 3.0)
    """

    def __init__(self):
        self.training = True

    def named_parameters(self, prefix: str = ""):
        seen = set()
        for name, value in vars(self).items():  # attributes in definition order
            if isinstance(value, Parameter) and id(value) not in seen:
                seen.add(id(value))
                yield prefix + name, value
            elif isinstance(value, Module):
                for n, p in value.named_parameters(prefix + name + "."):
                    if id(p) not in seen:
                        seen.add(id(p))
                        yield n, p

    def parameters(self):
        return [p for _, p in self.named_parameters()]

    def forward(self, *args, **kwargs):  # pragma: no cover - abstract
        raise NotImplementedError("Module.forward: define forward in the subclass")

    def __call__(self, *args, **kwargs):
        return self.forward(*args, **kwargs)

    def to(self, *args, **kwargs) -> Module:
        return self

    def train(self, mode: bool = True) -> Module:
        self.training = bool(mode)
        return self

    def eval(self) -> Module:
        return self.train(False)


_LAYERS = ("torch.nn layers are not emulated (no general autodiff): the NeRF tutorial's network "
           "is geofit's NeuralRadianceField in geofit.render (with its analytic backward) and "
           "geofit.fit.fit_nerf its fit; geofit.nn has Linear, Softplus, ReLU, Sigmoid and "
           "Sequential with forward/backward")
__getattr__ = missing_names("geofit.pytorch3d.nn", {
    "Linear": _LAYERS, "Sequential": _LAYERS, "Softplus": _LAYERS, "Sigmoid": _LAYERS,
    "ReLU": _LAYERS, "functional": _LAYERS,
})
