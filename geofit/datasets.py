"""The synthetic multi-view datasets of tutorials 4, 5 and 6: geofit's renders of the cow.

Each is a :class:`geofit.structures.MultiViewDataset` (the one dataset type; capture folders are
read into one by :func:`geofit.io.load_views`).

:func:`render_views` is the one renderer of synthetic datasets (PyTorch3D's
``generate_cow_renders`` and the fit_textured_mesh tutorial's dataset are both made with it):

* images: ``SoftPhongShader`` with ``PointLights(location=(0, 0, -3))``, one face per pixel, no
  blur, ``BlendParams(sigma=1e-4, gamma=1e-4, background_color=background)``, RGB only;
* silhouettes (``silhouettes=``): ``"soft"`` is the soft silhouette (sigma 1e-4, blur radius
  ``log(1 / 1e-4 - 1) * 1e-4``, 50 faces per pixel) as it is (tutorial 4's targets);
  ``"threshold"`` is the same thresholded at 1e-4, i.e. the pixels whose centre the mesh covers or
  comes within ``sqrt(blur_radius)`` NDC (about 1.9 px at 128 px) of, as 0/1 (tutorials 5 and 6);
  ``"coverage"`` is the hard render's coverage mask (tutorial 4's held-out views).

:func:`tutorial_views` renders the cow as a tutorial does, with held-out views attached:

* ``tutorial_views(4)``: fit_textured_mesh's 20 views at 128 px (``elev = linspace(0, 360)``,
  ``azim = linspace(-180, 180)``, white background, soft silhouettes) and 16 held-out views on a
  Fibonacci sphere with coverage masks;
* ``tutorial_views(5)`` / ``tutorial_views(6)``: ``generate_cow_renders``' 40 views at 128 px
  (elevation 0, ``azim = linspace(-180, 180, 40) + 180``, black background, thresholded
  silhouettes) and :func:`held_out_views` between the training azimuths at elevations 0 and 20.

The cow (``cow_mesh/cow.obj`` with its texture) is centred on its vertex mean and divided by its
largest absolute centred coordinate; without the cow files (see :mod:`geofit.data`) the
procedural textured stand-in is used and ``name`` says so.
"""
from __future__ import annotations

import math

import numpy as np

from ._validate import as_array, check_positive
from ._validate import check_int as _count
from .cameras import FoVPerspectiveCameras, look_at_view_transform
from .data import load_textured_mesh
from .io.mesh import load_mesh
from .render import (
    BlendParams,
    MeshRasterizer,
    MeshRenderer,
    PointLights,
    RasterizationSettings,
    SoftPhongShader,
)
from .render.soft import SoftRasterizationSettings, rasterize_soft, sigmoid_alpha_blend
from .structures.mesh import Mesh, as_mesh
from .structures.views import MultiViewDataset

__all__ = [
    "SILHOUETTE_KINDS",
    "TUTORIALS",
    "cow_mesh",
    "held_out_views",
    "render_views",
    "training_azimuths",
    "tutorial_views",
]

#: The silhouette renderer's blur radius in squared NDC units: ``log(1 / 1e-4 - 1) * 1e-4``.
SILHOUETTE_BLUR_RADIUS = float(np.log(1.0 / 1e-4 - 1.0) * 1e-4)

#: What :func:`render_views` can store as silhouettes (see the module docstring).
SILHOUETTE_KINDS = ("threshold", "soft", "coverage")

#: The tutorials :func:`tutorial_views` renders the dataset of.
TUTORIALS = (4, 5, 6)

_SIGMA = 1e-4


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


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


def _background(background) -> np.ndarray:
    bg = as_array(background, "background", (3,))
    if np.any(bg < 0) or np.any(bg > 1):
        raise ValueError(f"background: expected RGB values in [0, 1], got {bg.tolist()}")
    return bg


def _angles(azim, elev) -> tuple[np.ndarray, np.ndarray]:
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
    return np.ascontiguousarray(az, np.float64), np.ascontiguousarray(el, np.float64)


def render_views(mesh: Mesh, azim, elev, *, image_size: int = 128, dist: float = 2.7,
                 background=(0.0, 0.0, 0.0), light_location=(0.0, 0.0, -3.0),
                 silhouettes: str = "threshold", name: str = "mesh") -> MultiViewDataset:
    """Render a textured mesh from given angles: geofit's one renderer of synthetic datasets.

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
        Background colour of the images (black in tutorials 5 and 6, white in tutorial 4).
    light_location : (3,) float64
        World position of the point light (fixed in the world, as the tutorials').
    silhouettes : {"threshold", "soft", "coverage"}
        What to store as silhouettes (see the module docstring).
    name : str
        Stored in the result.

    Returns
    -------
    MultiViewDataset
        With ``lights``, ``azim``, ``elev``, ``dist`` and ``mesh`` set.
    """
    mesh = as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh
    if mesh.textures is None:
        raise ValueError("mesh: expected a textured mesh (TexturesUV or TexturesVertex)")
    size = _count(image_size, "image_size")
    dist = check_positive(dist, "dist")
    bg = _background(background)
    light = as_array(light_location, "light_location", (3,))
    if silhouettes not in SILHOUETTE_KINDS:
        raise ValueError(f"silhouettes: expected one of {SILHOUETTE_KINDS}, got "
                         f"{silhouettes!r}")
    az, el = _angles(azim, elev)
    R, T = look_at_view_transform(dist=dist, elev=el, azim=az)
    cameras = FoVPerspectiveCameras(R=R, T=T)
    lights = PointLights(location=[light.tolist()])
    rasterizer = MeshRasterizer(cameras=cameras, raster_settings=RasterizationSettings(
        image_size=size, blur_radius=0.0, faces_per_pixel=1))
    renderer = MeshRenderer(rasterizer=rasterizer, shader=SoftPhongShader(
        cameras=cameras, lights=lights, blend_params=BlendParams(
            sigma=_SIGMA, gamma=1e-4, background_color=tuple(bg.tolist()))))
    images = np.ascontiguousarray(renderer(mesh, cameras=cameras, lights=lights)[..., :3],
                                  dtype=np.float64)
    if silhouettes == "coverage":
        sil = rasterizer(mesh).mask.astype(np.float64)
    else:
        fragments = rasterize_soft(mesh, cameras, SoftRasterizationSettings(
            image_size=size, blur_radius=SILHOUETTE_BLUR_RADIUS, faces_per_pixel=50))
        sil = sigmoid_alpha_blend(fragments, _SIGMA)
        if silhouettes == "threshold":
            sil = (sil > 1e-4).astype(np.float64)
    return MultiViewDataset(
        images=images, silhouettes=sil, cameras=cameras,
        lights=lights, background=bg, name=name, azim=az, elev=el, dist=dist, mesh=mesh,
        config={"image_size": size, "dist": dist, "background": bg.tolist(),
                "light_location": light.tolist(), "silhouettes": silhouettes,
                "sigma": _SIGMA, "blur_radius": SILHOUETTE_BLUR_RADIUS, "faces_per_pixel": 50})


def held_out_views(num_views: int = 40, azimuth_range: float = 180.0, *,
                   elevations=(0.0, 20.0), n_azimuths: int | None = 8, image_size: int = 128,
                   background=(0.0, 0.0, 0.0), dist: float = 2.7,
                   mesh: Mesh | None = None) -> MultiViewDataset:
    """Evaluation views between the training azimuths of tutorials 5 and 6.

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
        As in :func:`tutorial_views`.

    Returns
    -------
    MultiViewDataset
        Views ordered by elevation, then azimuth, with thresholded silhouettes.
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
    name = "mesh"
    if mesh is None:
        mesh, name = cow_mesh()
    return render_views(mesh, np.tile(mids, len(el)), np.repeat(el, len(mids)),
                        image_size=image_size, dist=dist, background=background, name=name)


def _fibonacci_directions(n: int, offset: float = 0.5):
    """(elev, azim) in degrees of ``n`` nearly uniform directions (Fibonacci sphere)."""
    i = np.arange(n) + offset
    y = 1.0 - 2.0 * i / n
    elev = np.degrees(np.arcsin(np.clip(y, -1.0, 1.0)))
    azim = np.degrees((i * math.pi * (3.0 - math.sqrt(5.0))) % (2 * math.pi)) - 180.0
    return elev, azim


def tutorial_views(tutorial: int = 5, *, mesh: Mesh | None = None, num_views: int | None = None,
                   image_size: int = 128, num_held_out: int = 16, azimuth_range: float = 180.0,
                   elev: float = 0.0, dist: float = 2.7, background=None,
                   light_location=(0.0, 0.0, -3.0), name: str | None = None
                   ) -> MultiViewDataset:
    """A tutorial's training views of the cow (or of ``mesh``), with held-out views attached.

    Parameters
    ----------
    tutorial : {4, 5, 6}
        4: fit_textured_mesh (20 views, ``elev = linspace(0, 360)``, ``azim = linspace(-180,
        180)``, white background, soft silhouettes; held-out views on a Fibonacci sphere with
        coverage masks). 5, 6: ``generate_cow_renders`` (40 views at elevation ``elev``,
        :func:`training_azimuths`, black background, thresholded silhouettes; held-out views
        from :func:`held_out_views` at elevations 0 and 20, half of them at each).
    mesh : Mesh, optional
        Render this (textured, normalised) mesh instead of the normalised cow.
    num_views : int, optional
        Training views (20 for tutorial 4, 40 for 5 and 6).
    image_size : int
        Square image size (128).
    num_held_out : int
        Held-out views (16; an even number for tutorials 5 and 6; 0: none).
    azimuth_range, elev : float
        Tutorials 5 and 6: the azimuth range and the elevation of the training views.
    dist : float
        Camera distance (2.7).
    background : (3,) float, optional
        Image background (default: the tutorial's, white for 4 and black for 5 and 6).
    light_location : (3,) float
        The point light (0, 0, -3).
    name : str, optional
        Default: ``"cow"`` (or the stand-in's name), ``"mesh"`` for a given mesh.

    Returns
    -------
    MultiViewDataset
        Training views with ``held_out`` (or None) and ``mesh`` (the true surface) set.

    Examples
    --------
    >>> data = tutorial_views(5, num_views=4, image_size=32, num_held_out=2)
    >>> data.images.shape, data.silhouettes.shape, data.azim.tolist(), len(data.held_out)
    ((4, 32, 32, 3), (4, 32, 32), [0.0, 120.0, 240.0, 360.0], 2)
    """
    if tutorial not in TUTORIALS:
        raise ValueError(f"tutorial: expected one of {TUTORIALS}, got {tutorial!r}")
    n_views = _count(num_views if num_views is not None else (20 if tutorial == 4 else 40),
                     "num_views")
    n_held = _count(num_held_out, "num_held_out", 0)
    mesh_name = "mesh"
    if mesh is None:
        mesh, mesh_name = cow_mesh()
    name = mesh_name if name is None else name
    common = {"image_size": image_size, "dist": dist, "light_location": light_location,
              "name": name}
    if tutorial == 4:
        bg = (1.0, 1.0, 1.0) if background is None else background
        el = np.linspace(0.0, 360.0, n_views)
        az = np.linspace(-180.0, 180.0, n_views)
        data = render_views(mesh, az, el, background=bg, silhouettes="soft", **common)
        if n_held:
            he, ha = _fibonacci_directions(n_held)
            data.held_out = render_views(mesh, ha, he, background=bg, silhouettes="coverage",
                                         **common)
    else:
        bg = (0.0, 0.0, 0.0) if background is None else background
        e = float(elev)
        if not np.isfinite(e):
            raise ValueError(f"elev: expected a finite number, got {elev!r}")
        az = training_azimuths(n_views, azimuth_range)
        data = render_views(mesh, az, np.full(len(az), e), background=bg, **common)
        if n_held:
            if n_held % 2:
                raise ValueError(f"num_held_out: expected an even number for tutorial "
                                 f"{tutorial} (half at elevation 0, half at 20), got {n_held}")
            held = held_out_views(n_views, azimuth_range, n_azimuths=n_held // 2,
                                  image_size=image_size, background=bg, dist=dist, mesh=mesh)
            held.name = name
            data.held_out = held
    data.config.update(tutorial=tutorial, num_views=n_views, num_held_out=n_held)
    return data


def generate_cow_renders(num_views: int = 40, data_dir=None, azimuth_range: float = 180.0, *,
                         image_size: int = 128, mesh: Mesh | None = None):
    """The tutorials' helper (``docs/tutorials/utils/generate_cow_renders.py``): ``cameras,
    images, silhouettes`` as PyTorch3D's returns them, in geofit's types.

    The views of :func:`tutorial_views` ``(5, num_held_out=0)``: elevation 0,
    :func:`training_azimuths`, black background, silhouettes thresholded at 1e-4.

    Parameters
    ----------
    num_views : int
        Number of views (40).
    data_dir : str or path, optional
        A folder holding ``cow.obj`` (with its material and texture); default: geofit's cow
        (:func:`cow_mesh`).
    azimuth_range : float
        Azimuths ``linspace(-azimuth_range, azimuth_range, num_views) + 180`` degrees.
    image_size : int
        Square image size (128).
    mesh : Mesh, optional
        Render this (textured, normalised) mesh instead (not with ``data_dir``).

    Returns
    -------
    cameras : FoVPerspectiveCameras
        ``num_views`` cameras.
    images : (num_views, image_size, image_size, 3) float64
    silhouettes : (num_views, image_size, image_size) float64
        0 or 1.
    """
    if data_dir is not None:
        if mesh is not None:
            raise ValueError("data_dir, mesh: give one of them, not both")
        mesh = load_mesh(f"{data_dir}/cow.obj").normalize().mesh
    data = tutorial_views(5, mesh=mesh, num_views=num_views, image_size=image_size,
                          num_held_out=0, azimuth_range=azimuth_range)
    return data.cameras, data.images, data.silhouettes
