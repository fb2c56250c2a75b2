"""``torch.nn``: the modules of :mod:`geofit.pytorch3d.nn` and ``functional``."""
from ... import nn as _nn
from ...nn import Linear, Module, Parameter, ReLU, Sequential, Sigmoid, Softplus
from . import functional

__all__ = ["Linear", "Module", "Parameter", "ReLU", "Sequential", "Sigmoid", "Softplus",
           "functional"]

__getattr__ = _nn.__getattr__
