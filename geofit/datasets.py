"""Multi-view datasets rendered by geofit: PyTorch3D's ``generate_cow_renders`` and held-out views.

The volume and NeRF tutorials (and the mesh-from-views fit) train on renders of the cow made by
``docs/tutorials/utils/generate_cow_renders.py``. :func:`generate_cow_renders` makes the same
dataset with geofit's renderers:

* the cow (``cow_mesh/cow.obj`` with its texture) is centred on its vertex mean and divided by its
  largest absolute centred coordinate;
* cameras ``look_at_view_transform(dist=2.7, elev, azim)`` with ``elev`` constant (0) and
  ``azim = linspace(-azimuth_range, azimuth_range, num_views) + 180``, ``FoVPerspectiveCameras``
  (fov 60, znear 1, zfar 100);
* images: ``SoftPhongShader`` with ``PointLights(location=(0, 0, -3))``, one face per pixel, no
  blur, ``BlendParams(sigma=1e-4, gamma=1e-4, background_color=(0, 0, 0))``, RGB only;
* silhouettes: the soft silhouette (sigma 1e-4, blur radius ``log(1 / 1e-4 - 1) * 1e-4``, 50 faces
  per pixel) thresholded at 1e-4, i.e. the pixels whose centre the mesh covers or comes within
  ``sqrt(blur_radius)`` NDC (about 1.9 px at 128 px) of: the mesh's coverage of each pixel,
  slightly dilated, as 0/1.

:func:`held_out_views` renders the same scene from cameras between the training azimuths, at
several elevations, for evaluation. Without the cow files (see :mod:`geofit.data`), both fall back
to geofit's procedural textured stand-in and say so in ``mesh_name``.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from ._validate import as_array, check_positive
from .cameras import FoVPerspectiveCameras, look_at_view_transform
from .io.views import load_views, save_views
from .structures.mesh import Mesh, as_mesh

__all__ = [
    "MultiViewDataset",
    "cow_mesh",
    "generate_cow_renders",
    "held_out_views",
    "load_views",
    "render_views",
    "save_views",
    "training_azimuths",
]

#: The silhouette renderer's blur radius in squared NDC units: ``log(1 / 1e-4 - 1) * 1e-4``.
SILHOUETTE_BLUR_RADIUS = float(np.log(1.0 / 1e-4 - 1.0) * 1e-4)


@dataclass
class MultiViewDataset:
    """Posed renders of one scene.

    Attributes
    ----------
    images : (N, H, W, 3) float64
        RGB in [0, 1] (background as rendered, black for the tutorial).
    silhouettes : (N, H, W) float64
        0/1 silhouettes.
    cameras : FoVPerspectiveCameras
        The ``N`` cameras.
    azim : (N,) float64
        Azimuth of each camera (degrees).
    elev : (N,) float64
        Elevation of each camera (degrees).
    dist : float
        Camera distance from the origin.
    mesh_name : str
        ``"cow"``, or the procedural stand-in's name when the cow files were not found.
    """

    images: np.ndarray
    silhouettes: np.ndarray
    cameras: FoVPerspectiveCameras
    azim: np.ndarray
    elev: np.ndarray
    dist: float = 2.7
    mesh_name: str = "cow"

    def __len__(self) -> int:
        return int(self.images.shape[0])

    def __repr__(self) -> str:
        N, H, W = self.silhouettes.shape
        return (f"MultiViewDataset({N} views of {self.mesh_name!r}, {H}x{W}, "
                f"elev {sorted(set(np.round(self.elev, 3).tolist()))})")

    def subset(self, index) -> MultiViewDataset:
        """The views selected by ``index`` (int array, bool mask or slice)."""
        idx = np.arange(len(self))[index]
        idx = np.atleast_1d(idx)
        return MultiViewDataset(self.images[idx], self.silhouettes[idx], self.cameras[idx],
                                self.azim[idx], self.elev[idx], self.dist, self.mesh_name)


def cow_mesh() -> tuple[Mesh, str]:
    """The tutorial's cow, normalised as ``generate_cow_renders`` does.

    Returns
    -------
    mesh : Mesh
        Textured cow centred on its vertex mean, scaled so that the largest absolute coordinate
        is 1 (the procedural textured stand-in of :mod:`geofit.data` without the files).
    name : str
        ``"cow"`` or the stand-in's name.
    """
    from .data import load_textured_mesh

    mesh, name, _ = load_textured_mesh()
    return mesh.normalize().mesh, name


def training_azimuths(num_views: int = 40, azimuth_range: float = 180.0) -> np.ndarray:
    """``linspace(-azimuth_range, azimuth_range, num_views) + 180`` (degrees), as the tutorial.

    Examples
    --------
    >>> training_azimuths(5, 180.0)
    array([  0.,  90., 180., 270., 360.])
    """
    n = _count(num_views, "num_views")
    r = float(azimuth_range)
    if not np.isfinite(r):
        raise ValueError(f"azimuth_range: expected a finite number, got {azimuth_range!r}")
    return np.linspace(-r, r, n) + 180.0


def _count(value, name: str) -> int:
    if not isinstance(value, (numbers.Integral, np.integer)) or isinstance(value, bool) \
            or value < 1:
        raise ValueError(f"{name}: expected an integer >= 1, got {value!r}")
    return int(value)


def _background(background) -> np.ndarray:
    bg = as_array(background, "background", (3,))
    if np.any(bg < 0) or np.any(bg > 1):
        raise ValueError(f"background: expected RGB values in [0, 1], got {bg.tolist()}")
    return bg


def render_views(mesh: Mesh, azim, elev, *, image_size: int = 128, dist: float = 2.7,
                 background=(0.0, 0.0, 0.0), light_location=(0.0, 0.0, -3.0),
                 mesh_name: str = "mesh") -> MultiViewDataset:
    """Render a textured mesh the way ``generate_cow_renders`` does, from given angles.

    Parameters
    ----------
    mesh : Mesh
        A mesh with textures (already normalised as wanted).
    azim, elev : (N,) float64
        Camera azimuths and elevations in degrees (broadcast against each other).
    image_size : int
        Square image size in pixels.
    dist : float
        Camera distance.
    background : (3,) float64
        Background colour of the images.
    light_location : (3,) float64
        World position of the point light (fixed in the world, as the tutorial's).
    mesh_name : str
        Stored in the result.

    Returns
    -------
    MultiViewDataset
    """
    from .render import (
        BlendParams,
        MeshRasterizer,
        MeshRenderer,
        PointLights,
        RasterizationSettings,
        SoftPhongShader,
    )
    from .render.soft import SoftRasterizationSettings, rasterize_soft, sigmoid_alpha_blend

    mesh = as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh
    size = _count(image_size, "image_size")
    dist = check_positive(dist, "dist")
    bg = _background(background)
    light = as_array(light_location, "light_location", (3,))
    az = np.atleast_1d(as_array(azim, "azim"))
    el = np.atleast_1d(as_array(elev, "elev"))
    if az.ndim != 1 or el.ndim != 1:
        raise ValueError(f"azim, elev: expected scalars or 1-D arrays, got shapes {az.shape} "
                         f"and {el.shape}")
    try:
        az, el = np.broadcast_arrays(az, el)
    except ValueError:
        raise ValueError(f"azim, elev: shapes {az.shape} and {el.shape} do not broadcast") \
            from None
    az, el = np.ascontiguousarray(az), np.ascontiguousarray(el)
    R, T = look_at_view_transform(dist=dist, elev=el, azim=az)
    cameras = FoVPerspectiveCameras(R=R, T=T)
    lights = PointLights(location=[light.tolist()])
    renderer = MeshRenderer(
        rasterizer=MeshRasterizer(cameras=cameras, raster_settings=RasterizationSettings(
            image_size=size, blur_radius=0.0, faces_per_pixel=1)),
        shader=SoftPhongShader(cameras=cameras, lights=lights, blend_params=BlendParams(
            sigma=1e-4, gamma=1e-4, background_color=tuple(bg.tolist()))))
    images = renderer(mesh, cameras=cameras, lights=lights)[..., :3]
    fragments = rasterize_soft(mesh, cameras, SoftRasterizationSettings(
        image_size=size, blur_radius=SILHOUETTE_BLUR_RADIUS, faces_per_pixel=50))
    alpha = sigmoid_alpha_blend(fragments, 1e-4)
    silhouettes = (alpha > 1e-4).astype(np.float64)
    return MultiViewDataset(np.ascontiguousarray(images, dtype=np.float64), silhouettes, cameras,
                            az.astype(np.float64), el.astype(np.float64), dist, mesh_name)


def generate_cow_renders(num_views: int = 40, azimuth_range: float = 180.0,
                         image_size: int = 128, background=(0.0, 0.0, 0.0), elev: float = 0.0,
                         *, dist: float = 2.7, mesh: Mesh | None = None) -> MultiViewDataset:
    """The volume and NeRF tutorials' dataset: the cow seen from ``num_views`` azimuths.

    Parameters
    ----------
    num_views : int
        Number of views (40 in the tutorials).
    azimuth_range : float
        Azimuths are ``linspace(-azimuth_range, azimuth_range, num_views) + 180`` degrees (with
        the default 180 the first and last views coincide, as in the tutorial).
    image_size : int
        Square image size (128).
    background : (3,) float64
        Image background (black).
    elev : float
        Elevation of every view (0).
    dist : float
        Camera distance (2.7).
    mesh : Mesh, optional
        Render this mesh instead of the (normalised) cow.

    Returns
    -------
    MultiViewDataset
        ``images (N, S, S, 3)``, ``silhouettes (N, S, S)`` in {0, 1}, the cameras and angles.

    Examples
    --------
    >>> data = generate_cow_renders(num_views=4, image_size=32)
    >>> data.images.shape, data.silhouettes.shape, data.azim.tolist()
    ((4, 32, 32, 3), (4, 32, 32), [0.0, 120.0, 240.0, 360.0])
    """
    az = training_azimuths(num_views, azimuth_range)
    e = float(elev)
    if not np.isfinite(e):
        raise ValueError(f"elev: expected a finite number, got {elev!r}")
    name = "mesh"
    if mesh is None:
        mesh, name = cow_mesh()
    return render_views(mesh, az, np.full(len(az), e), image_size=image_size, dist=dist,
                        background=background, mesh_name=name)


def held_out_views(num_views: int = 40, azimuth_range: float = 180.0, *,
                   elevations=(0.0, 20.0), n_azimuths: int | None = 8, image_size: int = 128,
                   background=(0.0, 0.0, 0.0), dist: float = 2.7,
                   mesh: Mesh | None = None) -> MultiViewDataset:
    """Evaluation views between the training azimuths of :func:`generate_cow_renders`.

    The azimuths are the midpoints between consecutive training azimuths (none of them is a
    training view); ``n_azimuths`` of them, evenly spread around the circle, are rendered at every
    elevation in ``elevations``.

    Parameters
    ----------
    num_views, azimuth_range : int, float
        The training set's settings (the midpoints are taken between its azimuths).
    elevations : sequence of float
        Elevations in degrees (0 and 20: the training elevation and a view from above).
    n_azimuths : int or None
        How many midpoints to use per elevation (None: all ``num_views - 1``).
    image_size, background, dist, mesh
        As in :func:`generate_cow_renders`.

    Returns
    -------
    MultiViewDataset
        Views ordered by elevation, then azimuth.
    """
    train = training_azimuths(num_views, azimuth_range)
    if len(train) < 2:
        raise ValueError("num_views: expected at least 2 training views to place views between")
    mids = 0.5 * (train[1:] + train[:-1])
    if n_azimuths is not None:
        k = _count(n_azimuths, "n_azimuths")
        if k > len(mids):
            raise ValueError(f"n_azimuths: expected at most {len(mids)}, got {k}")
        pick = np.unique(np.round(np.linspace(0, len(mids), k, endpoint=False)).astype(int))
        mids = mids[pick]
    el = np.atleast_1d(as_array(elevations, "elevations"))
    if el.ndim != 1 or el.size == 0:
        raise ValueError(f"elevations: expected a non-empty 1-D sequence, got shape {el.shape}")
    az_all = np.tile(mids, len(el))
    el_all = np.repeat(el, len(mids))
    name = "mesh"
    if mesh is None:
        mesh, name = cow_mesh()
    return render_views(mesh, az_all, el_all, image_size=image_size, dist=dist,
                        background=background, mesh_name=name)
