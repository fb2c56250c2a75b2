"""Geometric operators: surface sampling (with its sparse Jacobian) and Laplacian matrices."""
from . import laplacian, sampling
from .laplacian import *  # noqa: F403 - the public names are the submodules' __all__
from .sampling import *  # noqa: F403

__all__ = sorted([*laplacian.__all__, *sampling.__all__])
