"""PyTorch3D's tutorial API over geofit: change the imports, keep the code.

``from pytorch3d.X import Y`` becomes ``from geofit.pytorch3d.X import Y`` for the modules
``io``, ``structures``, ``ops``, ``loss``, ``renderer``, ``utils`` and ``vis``; torch's tensor
creation, optimisers and the few ``torch.nn`` pieces the tutorials use come from
:mod:`geofit.pytorch3d.tensor`, :mod:`geofit.pytorch3d.optim` and :mod:`geofit.pytorch3d.nn`. Everything is numpy underneath; gradients come from geofit's
hand-written vector-Jacobian products, recorded on a tape (:class:`~.tensor.Tensor`) so that
``loss.backward()`` and ``optimizer.step()`` work as in the tutorials. A PyTorch3D name that is
not provided raises an AttributeError (ImportError in ``from ... import``) that says what to use
instead.
"""
from . import io, loss, nn, ops, optim, renderer, structures, tensor, transforms, utils, vis
from ._common import missing_names
from .tensor import Parameter, Tensor, full, manual_seed, no_grad

__all__ = ["Parameter", "Tensor", "full", "io", "loss", "manual_seed", "nn", "no_grad", "ops",
           "optim", "renderer", "structures", "tensor", "transforms", "utils",
           "vis"]

__getattr__ = missing_names("geofit.pytorch3d", {
    "implicitron": "not provided; the NeRF tutorial's model is "
                   "geofit's NeuralRadianceField (geofit.render)",
    "datasets": "geofit.datasets.tutorial_views, geofit.data for the tutorial files",
})
