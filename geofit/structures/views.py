"""Posed views of one scene: the one multi-view dataset type of geofit.

:class:`MultiViewDataset` holds images, silhouettes, cameras, the lights (when known), optional
held-out views (another :class:`MultiViewDataset`) and the true mesh when known. Every
multi-view fit (:func:`geofit.fit_mesh_to_views`, :func:`geofit.fit_volume`,
:func:`geofit.fit_nerf`) takes one; :func:`geofit.io.load_views` builds one from a capture
folder and :func:`geofit.datasets.tutorial_views` renders the tutorials' ones.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from .._validate import as_array, as_unit_images, check_positive
from .._validate import check_int as _count
from ..cameras import CamerasBase
from .mesh import Mesh

__all__ = ["UNKNOWN_SILHOUETTES", "MultiViewDataset"]

#: What a dataset without silhouettes means, and what the fits do then.
UNKNOWN_SILHOUETTES = (
    "silhouettes unknown: the capture has no masks and no alpha channel. fit_volume and "
    "fit_nerf fit without them (every pixel is taken as showing the scene: no carving, the "
    "background becomes part of the fit); fit_mesh_to_views needs them. To make masks: segment "
    "the object in each image (e.g. rembg, Segment Anything, or a chroma key) and save them as "
    "the images' alpha channel (RGBA PNGs), as masks/NAME.png beside images/ (COLMAP), as "
    "frames[i].mask_path (transforms.json) or views[i].mask (cameras.json)")


@dataclass(kw_only=True)
class MultiViewDataset:
    """Posed views of one scene (keyword-only construction).

    Attributes
    ----------
    images : (N, H, W, 3) float64 or None
        RGB in [0, 1] (None for silhouettes only).
    silhouettes : (N, H, W) float64 or None
        Silhouettes in [0, 1] (soft or binary); None when unknown (a capture without masks or
        alpha, see :data:`UNKNOWN_SILHOUETTES`), then ``images`` are required.
    cameras : CamerasBase
        The ``N`` cameras (PyTorch3D conventions).
    lights : PointLights, DirectionalLights or AmbientLights, optional
        The lights the images were rendered with, when known (synthetic datasets). None (a
        capture: its lighting is in its pixels): the fits that shade fit unlit colour, what
        the camera saw (``AmbientLights()``).
    background : (3,) float64, optional
        The colour behind the object in ``images`` when known (from a capture's alpha or
        metadata, or the renderer's); held-out figures are rendered on it.
    name : str
        What the views show (``"cow"``, the stand-in's name, a capture's folder name).
    azim, elev : (N,) float64, optional
        Azimuth and elevation of each camera (degrees) when known.
    dist : float, optional
        Camera distance from the origin when all cameras share one.
    held_out : MultiViewDataset, optional
        Views for evaluation only (may be set after construction).
    mesh : Mesh, optional
        The true surface, when known (synthetic datasets).
    config : dict
        How the views were made (free-form, JSON-ready).

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    >>> ds = MultiViewDataset(images=np.zeros((2, 8, 8, 3)), silhouettes=np.zeros((2, 8, 8)),
    ...                       cameras=FoVPerspectiveCameras(R=R, T=T), name="empty")
    >>> len(ds), ds.image_size, len(ds[1:]), ds.downsample(2).image_size
    (2, (8, 8), 1, (4, 4))
    """

    images: np.ndarray | None
    silhouettes: np.ndarray
    cameras: CamerasBase
    lights: Any = None
    background: np.ndarray | None = None
    name: str = ""
    azim: np.ndarray | None = None
    elev: np.ndarray | None = None
    dist: float | None = None
    held_out: MultiViewDataset | None = None
    mesh: Mesh | None = None
    config: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.cameras, CamerasBase):
            raise TypeError(f"cameras: expected a geofit camera batch, got {type(self.cameras)!r}")
        n = len(self.cameras)
        if n == 0:
            raise ValueError("cameras: expected at least one camera, got 0")
        if self.silhouettes is None:
            if self.images is None:
                raise ValueError("silhouettes, images: expected at least one of them, got None "
                                 "for both")
            self.images = as_unit_images(self.images, "images", (n, None, None, 3))
            H, W = self.images.shape[1:3]
        else:
            self.silhouettes = as_array(self.silhouettes, "silhouettes", (None, None, None))
            if self.silhouettes.shape[0] != n:
                raise ValueError(f"silhouettes, cameras: expected one camera per view, got "
                                 f"{self.silhouettes.shape[0]} silhouettes and {n} cameras")
            H, W = self.silhouettes.shape[1:]
            _check_size(H, W, "silhouettes")
            _check_unit_range(self.silhouettes, "silhouettes")
            if self.images is not None:
                self.images = as_unit_images(self.images, "images", (n, H, W, 3))
        _check_size(H, W, "images" if self.silhouettes is None else "silhouettes")
        if self.images is not None:
            _check_unit_range(self.images, "images")
        if self.background is not None:
            self.background = as_array(self.background, "background", (3,))
            _check_unit_range(self.background, "background")
        if not isinstance(self.name, str):
            raise TypeError(f"name: expected a str, got {type(self.name)!r}")
        for nm in ("azim", "elev"):
            v = getattr(self, nm)
            if v is not None:
                setattr(self, nm, as_array(np.atleast_1d(v), nm, (n,)))
        if self.dist is not None:
            self.dist = check_positive(self.dist, "dist")
        if self.held_out is not None and not isinstance(self.held_out, MultiViewDataset):
            raise TypeError(f"held_out: expected a MultiViewDataset or None, got "
                            f"{type(self.held_out)!r}")
        if self.mesh is not None and not isinstance(self.mesh, Mesh):
            raise TypeError(f"mesh: expected a geofit Mesh or None, got {type(self.mesh)!r}")

    # -- size and selection
    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def image_size(self) -> tuple[int, int]:
        """``(H, W)`` in pixels."""
        a = self.images if self.silhouettes is None else self.silhouettes
        return int(a.shape[1]), int(a.shape[2])

    def require_silhouettes(self, fit: str) -> np.ndarray:
        """The silhouettes, or a ValueError for ``fit`` saying how to make them."""
        if self.silhouettes is None:
            raise ValueError(f"dataset: {fit} needs silhouettes and {self.name!r} has none "
                             f"({UNKNOWN_SILHOUETTES})")
        return self.silhouettes

    def __repr__(self) -> str:
        N, (H, W) = len(self), self.image_size
        parts = [f"{N} views of {self.name!r}", f"{H}x{W}"]
        if self.images is None:
            parts.append("silhouettes only")
        if self.silhouettes is None:
            parts.append("silhouettes unknown")
        if self.held_out is not None:
            parts.append(f"{len(self.held_out)} held out")
        return f"MultiViewDataset({', '.join(parts)})"

    def __getitem__(self, index) -> MultiViewDataset:
        """The views selected by ``index`` (int, int array, bool mask or slice), as a dataset
        (held-out views, mesh and lights kept)."""
        idx = np.atleast_1d(np.arange(len(self))[index])
        return self._replace(
            images=None if self.images is None else self.images[idx],
            silhouettes=None if self.silhouettes is None else self.silhouettes[idx],
            cameras=self.cameras[idx],
            azim=None if self.azim is None else self.azim[idx],
            elev=None if self.elev is None else self.elev[idx])

    def subset(self, index) -> MultiViewDataset:
        """Same as ``dataset[index]``."""
        return self[index]

    def split(self, held_out=8) -> MultiViewDataset:
        """Training views with the others attached as :attr:`held_out`.

        Parameters
        ----------
        held_out : int, or (k,) int64 / (N,) bool / slice
            An int ``k``: every ``k``-th view from the first is held out (LLFF's ``llffhold``
            convention, 8 by default); otherwise the held-out views themselves, as for
            ``dataset[index]``.

        Returns
        -------
        MultiViewDataset
            The remaining views, with ``held_out`` set to the selected ones (whose own
            ``held_out`` is None).

        Raises
        ------
        ValueError
            If no view would be left for training or none would be held out.

        Examples
        --------
        >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
        >>> R, T = look_at_view_transform(2.7, 0.0, np.arange(10) * 36.0)
        >>> ds = MultiViewDataset(images=None, silhouettes=np.zeros((10, 4, 4)),
        ...                       cameras=FoVPerspectiveCameras(R=R, T=T))
        >>> train = ds.split(4)
        >>> len(train), len(train.held_out), train.held_out.held_out is None
        (7, 3, True)
        """
        n = len(self)
        test = np.zeros(n, dtype=bool)
        if isinstance(held_out, (int, np.integer)) and not isinstance(held_out, bool):
            k = _count(held_out, "held_out")
            test[::k] = True
        else:
            try:
                test[np.arange(n)[held_out]] = True
            except (IndexError, TypeError, ValueError) as exc:
                raise ValueError(f"held_out: expected an int step or an index of the {n} "
                                 f"views, got {held_out!r} ({exc})") from None
        if test.all() or not test.any():
            raise ValueError(f"held_out: expected to hold out some but not all of the {n} "
                             f"views, got {int(test.sum())} held out")
        train = self[~test]
        train.held_out = self[test]._replace(held_out=None)
        return train

    def downsample(self, factor: int) -> MultiViewDataset:
        """Average ``factor x factor`` pixel blocks (a coarser level of the same views)."""
        factor = _count(factor, "factor")
        if factor == 1:
            return self
        n, (H, W) = len(self), self.image_size
        if H % factor or W % factor:
            raise ValueError(f"factor: {factor} does not divide the image size {(H, W)}")
        h, w = H // factor, W // factor
        sil = None
        if self.silhouettes is not None:
            sil = self.silhouettes.reshape(n, h, factor, w, factor).mean(axis=(2, 4))
        img = None
        if self.images is not None:
            img = self.images.reshape(n, h, factor, w, factor, 3).mean(axis=(2, 4))
        return self._replace(images=img, silhouettes=sil)

    def _replace(self, **changes) -> MultiViewDataset:
        """A :class:`MultiViewDataset` (never a subclass) with ``changes``."""
        kw = {f.name: getattr(self, f.name) for f in fields(MultiViewDataset)}
        kw.update(changes)
        return MultiViewDataset(**kw)


def _check_size(H: int, W: int, name: str) -> None:
    if H < 2 or W < 2:
        raise ValueError(f"{name}: expected images of at least 2 x 2 pixels, got {(H, W)}")


def _check_unit_range(a: np.ndarray, name: str) -> None:
    lo, hi = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
    if lo < 0.0 or hi > 1.0:
        raise ValueError(f"{name}: expected values in [0, 1], got values in [{lo:g}, {hi:g}]")
