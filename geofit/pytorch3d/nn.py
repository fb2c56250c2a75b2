"""``torch.nn`` pieces the tutorials use that carry over: ``Parameter``.

``torch.nn.Module`` subclasses (the volume and NeRF tutorials' models) are not emulated: geofit's
models have analytic backward passes (:class:`geofit.render.implicit.NeuralRadianceField`,
:func:`geofit.fit.fit_volume`).
"""
from ._common import missing_names
from .tensor import Parameter

__all__ = ["Parameter"]

_MODULE = ("torch.nn modules are not emulated (no general autodiff); the tutorials' models are "
           "geofit.render.implicit.NeuralRadianceField (NeRF, with its backward pass) and "
           "geofit.fit.fit_volume (voxel volume); geofit.nn has Linear, Softplus, ReLU, "
           "Sigmoid and Sequential with forward/backward")
__getattr__ = missing_names("geofit.pytorch3d.nn", {
    "Module": _MODULE, "Linear": _MODULE, "Sequential": _MODULE, "Softplus": _MODULE,
    "Sigmoid": _MODULE, "ReLU": _MODULE,
})
