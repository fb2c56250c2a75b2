"""``torch.optim``: :class:`SGD` and :class:`Adam` over tape tensors
(:mod:`geofit.pytorch3d.optim`)."""
from ..optim import SGD, Adam, Optimizer

__all__ = ["SGD", "Adam", "Optimizer"]
