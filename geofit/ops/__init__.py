"""Geometric operators: surface sampling (with its sparse Jacobian), Laplacian matrices,
topology reports and remeshing."""
from . import laplacian, sampling
from .laplacian import *  # noqa: F403 - the public names are the submodules' __all__
from .remesh import RemeshResult, remesh
from .sampling import *  # noqa: F403
from .topology import TopologyReport, topology

__all__ = sorted([*laplacian.__all__, *sampling.__all__, "RemeshResult", "TopologyReport",
                  "remesh", "topology"])
