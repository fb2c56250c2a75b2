"""Names of the former multi-view dataset stack of :mod:`geofit.fit.views`, kept for one release.

Everything here warns with a :class:`DeprecationWarning` and forwards to
:class:`geofit.datasets.MultiViewDataset` and :func:`geofit.datasets.tutorial_views`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

from ..structures import MultiViewDataset
from ..datasets import tutorial_views
from ..structures import Mesh
from ._options import warn_deprecated

__all__ = ["MultiViewData", "MultiViewSplit", "cow_multiview_dataset",
           "render_multiview_dataset"]


class MultiViewData(MultiViewDataset):
    """Deprecated: ``MultiViewDataset(images=..., silhouettes=..., cameras=..., lights=...)``."""

    def __init__(self, cameras, silhouettes, images=None, lights: Any = None):
        warn_deprecated("geofit.fit.views.MultiViewData(cameras, silhouettes, images, lights)",
                        "geofit.datasets.MultiViewDataset(images=..., silhouettes=..., "
                        "cameras=..., lights=...)")
        super().__init__(images=images, silhouettes=silhouettes, cameras=cameras, lights=lights)


@dataclass
class MultiViewSplit:
    """Deprecated: a :class:`~geofit.datasets.MultiViewDataset` holds ``held_out`` and ``mesh``."""

    train: MultiViewDataset
    heldout: MultiViewDataset
    mesh: Mesh
    name: str = ""
    config: dict = field(default_factory=dict)

    def __post_init__(self):
        warn_deprecated("geofit.fit.views.MultiViewSplit", "geofit.datasets.MultiViewDataset "
                        "(its held_out and mesh fields)", stacklevel=4)


def _split(data: MultiViewDataset) -> MultiViewSplit:
    train = MultiViewDataset(images=data.images, silhouettes=data.silhouettes,
                             cameras=data.cameras, lights=data.lights, name=data.name,
                             azim=data.azim, elev=data.elev, dist=data.dist, mesh=data.mesh,
                             config=data.config)
    with warnings.catch_warnings():  # the caller was warned already
        warnings.simplefilter("ignore", DeprecationWarning)
        return MultiViewSplit(train, data.held_out, data.mesh, data.name, data.config)


def render_multiview_dataset(mesh: Mesh, *, num_views: int = 20, image_size: int = 128,
                             num_heldout: int = 16, dist: float = 2.7,
                             light_location=(0.0, 0.0, -3.0), name: str = "") -> MultiViewSplit:
    """Deprecated: ``geofit.datasets.tutorial_views(4, mesh=mesh, ...)``."""
    warn_deprecated("render_multiview_dataset", "geofit.datasets.tutorial_views(4, mesh=...)")
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh: expected a Mesh, got {type(mesh)!r}")
    return _split(tutorial_views(4, mesh=mesh, num_views=num_views, image_size=image_size,
                                 num_held_out=num_heldout, dist=dist,
                                 light_location=light_location, name=name))


def cow_multiview_dataset(*, num_views: int = 20, image_size: int = 128,
                          num_heldout: int = 16) -> MultiViewSplit:
    """Deprecated: ``geofit.datasets.tutorial_views(4, ...)``."""
    warn_deprecated("cow_multiview_dataset", "geofit.datasets.tutorial_views(4, ...)")
    return _split(tutorial_views(4, num_views=num_views, image_size=image_size,
                                 num_held_out=num_heldout))
