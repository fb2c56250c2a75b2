"""PyTorch3D's tutorial API over geofit: change the imports, keep the code.

``from pytorch3d.X import Y`` becomes ``from geofit.pytorch3d.X import Y`` for the modules
``io``, ``structures``, ``ops``, ``loss``, ``renderer``, ``transforms``, ``utils`` and ``vis``,
and ``import torch`` becomes ``import geofit.pytorch3d.torch as torch`` (:mod:`.torch` lists
the torch names provided). The tutorials' helper files (``utils/generate_cow_renders.py``,
``utils/plot_image_grid.py``) are in :mod:`.tutorial_utils`.

Everything is numpy underneath; gradients come from geofit's hand-written vector-Jacobian
products, recorded on a tape (:class:`~.tensor.Tensor`) so that ``loss.backward()`` and
``optimizer.step()`` work as in the tutorials. A PyTorch3D name that geofit does not provide
imports, and raises NotImplementedError saying what to use instead when it is used.
"""
from . import (
    io,
    loss,
    nn,
    ops,
    optim,
    renderer,
    structures,
    tensor,
    torch,
    transforms,
    tutorial_utils,
    utils,
    vis,
)
from ._common import missing_names
from .tensor import Parameter, Tensor, full, manual_seed, no_grad

__all__ = ["Parameter", "Tensor", "full", "io", "loss", "manual_seed", "nn", "no_grad", "ops",
           "optim", "renderer", "structures", "tensor", "torch", "transforms", "tutorial_utils",
           "utils", "vis"]

__getattr__ = missing_names("geofit.pytorch3d", {
    "implicitron": "not provided; the NeRF tutorial's model is "
                   "geofit's NeuralRadianceField (geofit.render)",
    "datasets": "not provided (ShapeNet, R2N2); the tutorials' cow renders are "
                "geofit.pytorch3d.tutorial_utils.generate_cow_renders",
})
