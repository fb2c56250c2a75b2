"""``torch.nn.functional``: ``normalize``, ``grid_sample``, ``relu``, ``sigmoid``, ``softplus``
(:mod:`geofit.pytorch3d._functional`)."""
from ..._functional import grid_sample, normalize, relu, sigmoid, softplus

__all__ = ["grid_sample", "normalize", "relu", "sigmoid", "softplus"]
