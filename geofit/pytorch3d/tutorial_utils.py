"""The PyTorch3D tutorials' own helper files (``docs/tutorials/utils``), on geofit.

The volume and NeRF tutorials import ``generate_cow_renders`` and ``image_grid`` from the
``utils`` folder beside the notebooks: ``from utils.generate_cow_renders import
generate_cow_renders`` becomes ``from geofit.pytorch3d.tutorial_utils import
generate_cow_renders`` (and likewise ``image_grid``). The tutorials' files themselves, with
their imports changed, also run on :mod:`geofit.pytorch3d`; these are geofit's faster versions
(Embree for the images) with the same return values.
"""
from __future__ import annotations

from .. import datasets as _datasets
from ..render.utils import image_grid
from .renderer.cameras import FoVPerspectiveCameras
from .tensor import Tensor

__all__ = ["generate_cow_renders", "image_grid"]


def generate_cow_renders(num_views: int = 40, data_dir=None, azimuth_range: float = 180.0, *,
                         image_size: int = 128):
    """``cameras, images, silhouettes`` of the cow, as the tutorials' helper returns them.

    Parameters
    ----------
    num_views : int
        Number of views (40), at elevation 0 and azimuths
        ``linspace(-azimuth_range, azimuth_range, num_views) + 180`` degrees.
    data_dir : str, optional
        A folder with ``cow.obj``, its material and texture; default: geofit's cow
        (:func:`geofit.datasets.cow_mesh`).
    azimuth_range : float
        Half the range of azimuths, degrees (180).
    image_size : int
        Square image size (128, the tutorials').

    Returns
    -------
    cameras : FoVPerspectiveCameras
        A batch of ``num_views`` cameras (``cameras.R[idx]``, ``len(cameras)``, ``.to(device)``).
    images : (num_views, image_size, image_size, 3) Tensor
        RGB renders on a black background.
    silhouettes : (num_views, image_size, image_size) Tensor
        1 where the soft silhouette exceeds 1e-4, else 0.

    See Also
    --------
    geofit.datasets.generate_cow_renders : the same views as numpy arrays and geofit cameras.
    """
    cams, images, silhouettes = _datasets.generate_cow_renders(
        num_views, data_dir, azimuth_range, image_size=image_size)
    cameras = FoVPerspectiveCameras(R=cams.R, T=cams.T, znear=cams.znear, zfar=cams.zfar,
                                    aspect_ratio=cams.aspect_ratio, fov=cams.fov)
    return cameras, Tensor(images), Tensor(silhouettes)
