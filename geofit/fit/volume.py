"""Fit a voxel volume of densities and colours to posed images (PyTorch3D's fifth tutorial).

The tutorial (``fit_textured_volume``) optimises a dense ``128^3`` grid of log-densities and
colour logits, renders it with ``NDCMultinomialRaysampler`` (150 samples per ray over view depths
[0.1, 3.0]) and PyTorch3D's emission-absorption raymarcher, and minimises Huber losses (scale 0.1)
on the colours and the silhouettes with Adam (lr 0.1, 300 steps of 10 random views, lr x 0.1 at
75%). :func:`fit_volume` with ``recipe="tutorial"`` runs exactly that recipe, with analytic
gradients (the raymarcher's vector-Jacobian product, then the transpose of the sparse trilinear
operator, then the sigmoids).

geofit's own recipe (``"default"``; methods ``"lbfgs"``, ``"lbfgs-nlopt"``, ``"adam"``) fits the
same model and the same renderer, but keeps the problem as small as the scene allows:

* **visual hull**: a voxel can be occupied only if its trilinear footprint projects into every
  silhouette (:func:`visual_hull`); all other voxels are fixed empty;
* **coarse to fine**: the grid is fitted at ``levels`` (e.g. 32^3, 64^3, 128^3) with images
  downsampled to match and samples per ray scaled with the resolution; between levels the
  extinction ``sigma = -log(1 - d) / step`` is upsampled trilinearly (so the per-sample opacities
  stay consistent when the sample spacing changes) and the hull is carved again at the new
  resolution;
* **pruning**: at each new level only voxels near the occupied region of the previous level (and
  inside the hull) may hold density;
* **empty-space skipping**: each ray marches only the contiguous range of samples whose trilinear
  cell touches a voxel that may hold density, and (from the second level on) stops once the
  transmittance of the upsampled model falls below ``termination`` (its samples further on add
  less than that to the pixel); voxels that no remaining sample reads keep their values and are
  not optimised;
* **full-batch solves**: all rays of all views form one deterministic objective, so L-BFGS can
  run its line search; the sparse sampling operator of a level is built once and reused;
* **a smoothness prior** (``smoothness``): the mean squared difference between neighbouring free
  voxels, which fills what no training view constrains (the top of the cow: the tutorial's
  cameras are all at elevation 0) smoothly; it raised the held-out PSNR at elevation 20 by about
  1 dB in the measurements behind the default.

Sampled values, ray marching and sparse products run in float32 by default (``precision``), on
geofit's threads (:func:`geofit.get_num_threads`); the loss is accumulated and the parameters
kept in float64.

Every result reports the number of free voxels (``n_active_voxels``) and the mean number of
samples marched per ray (``samples_per_ray``).

Notes
-----
Gradients flow to the voxel values only: which voxels a sample reads, which samples a ray keeps
and which voxels are free are piecewise-constant choices made when a level is set up.
"""
from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._threads import one_blas_thread
from .._validate import as_array, as_rng, check_choice, check_positive
from ..cameras import CamerasBase
from ..loss.robust import huber
from ..metrics import psnr as image_psnr
from ..render.volume.raysampling import NDCMultinomialRaysampler
from ..structures.volume import Volume, visual_hull
from ._options import (
    Recipes,
    check_int,
    dataset_argument,
    method_name,
    recipe_name,
    warn_deprecated,
)
from ._volume_levels import _fit_tutorial, _LevelsFit, _VolumeOptions
from .history import FitResult

__all__ = [
    "FIT_VOLUME_METHODS",
    "RECIPES",
    "VolumeFitResult",
    "VolumeMetrics",
    "fit_volume",
    "huber",
    "render_volume",
    "visual_hull",
    "volume_metrics",
]

#: Methods accepted by :func:`fit_volume`.
FIT_VOLUME_METHODS = ("lbfgs", "lbfgs-nlopt", "adam")

#: Recipes of :func:`fit_volume`: geofit's reduced model, or the tutorial's dense grid and Adam.
RECIPES: dict[str, dict] = Recipes({"default": {"method": "lbfgs"},
                                    "tutorial": {"method": "adam"}}, fit="fit_volume")

_EPS = 1e-10          # PyTorch3D's EA eps
_LOGIT_CLIP = 1e-6    # opacities/colours are kept in [clip, 1 - clip] when converted to logits


def _check_cameras(cameras, n: int) -> CamerasBase:
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit cameras batch, got {type(cameras)!r}")
    if len(cameras) != n:
        raise ValueError(f"cameras: expected {n} cameras (one per image), got {len(cameras)}")
    return cameras


# --------------------------------------------------------------------------------------------
# Rendering and metrics
# --------------------------------------------------------------------------------------------


def render_volume(volume: Volume, cameras: CamerasBase, image_size=128, *,
                  n_pts_per_ray: int = 150, min_depth: float = 0.1,
                  max_depth: float = 3.0) -> np.ndarray:
    """Render a volume as the tutorial does (its raysampler and PyTorch3D's EA raymarcher).

    Parameters
    ----------
    volume : Volume
        Densities as per-sample opacities, RGB features.
    cameras : CamerasBase
        ``N`` cameras.
    image_size : int or (H, W)
        Image size in pixels.
    n_pts_per_ray, min_depth, max_depth
        The tutorial's ``NDCMultinomialRaysampler`` settings (150 samples over [0.1, 3.0]).

    Returns
    -------
    images : (N, H, W, C + 1) float64
        Colours and opacity (empty-space skipping makes this fast; the result is the full
        ray march's).

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> vol = Volume(np.full((8, 8, 8), 0.5), np.ones((3, 8, 8, 8)), voxel_size=3.0 / 8)
    >>> images = render_volume(vol, FoVPerspectiveCameras(R=R, T=T), 16, n_pts_per_ray=32)
    >>> images.shape, bool(images[0, 8, 8, 3] > 0.99), bool(np.allclose(images[..., :3], 1.0))
    ((1, 16, 16, 4), True, False)
    """
    from ..render.volume.raymarching import EmissionAbsorptionRaymarcher
    from ..render.volume import VolumeRenderer

    if isinstance(image_size, (numbers.Integral, np.integer)):
        image_size = (int(image_size), int(image_size))
    H, W = (int(v) for v in image_size)
    renderer = VolumeRenderer(NDCMultinomialRaysampler(
        image_width=W, image_height=H, n_pts_per_ray=n_pts_per_ray, min_depth=min_depth,
        max_depth=max_depth), EmissionAbsorptionRaymarcher(), chunk_size=1 << 19)
    return renderer(cameras, volume)[0]


@dataclass
class VolumeMetrics:
    """Held-out accuracy of a volume (see :func:`volume_metrics`).

    Attributes
    ----------
    psnr : float
        Mean over views of the per-view PSNR (dB) of the RGB render against the target,
        ``10 log10(1 / MSE)`` over all pixels and channels (black background included;
        :func:`geofit.metrics.psnr`, inf for a view rendered exactly).
    iou : float
        Mean over views of the IoU between ``opacity > 0.5`` and ``silhouette > 0.5``.
    psnr_per_view, iou_per_view : (N,) float64
    images : (N, H, W, 4) float64
        The renders (RGB, opacity).
    """

    psnr: float
    iou: float
    psnr_per_view: np.ndarray
    iou_per_view: np.ndarray
    images: np.ndarray

    def as_dict(self) -> dict:
        return {"psnr": self.psnr, "iou": self.iou}


def volume_metrics(volume: Volume, images, silhouettes, cameras: CamerasBase, *,
                   n_pts_per_ray: int = 150, min_depth: float = 0.1,
                   max_depth: float = 3.0) -> VolumeMetrics:
    """PSNR and silhouette IoU of a volume's renders against target views.

    Parameters
    ----------
    volume : Volume
    images : (N, H, W, 3) float64
        Target RGB.
    silhouettes : (N, H, W) float64
        Target silhouettes.
    cameras : CamerasBase
        The ``N`` cameras.
    n_pts_per_ray, min_depth, max_depth
        Ray sampling of the renders (the tutorial's by default).

    Returns
    -------
    VolumeMetrics
    """
    imgs = as_array(images, "images", (None, None, None, 3))
    N, H, W, _ = imgs.shape
    sils = as_array(silhouettes, "silhouettes", (N, H, W))
    cameras = _check_cameras(cameras, N)
    out = render_volume(volume, cameras, (H, W), n_pts_per_ray=n_pts_per_ray,
                        min_depth=min_depth, max_depth=max_depth)
    psnr = image_psnr(out[..., :3], imgs, per_image=True)
    pred = out[..., 3] > 0.5
    gt = sils > 0.5
    union = (pred | gt).sum(axis=(1, 2))
    iou = np.where(union > 0, (pred & gt).sum(axis=(1, 2)) / np.maximum(union, 1), 1.0)
    return VolumeMetrics(float(psnr.mean()), float(iou.mean()), psnr, iou, out)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------


@dataclass(kw_only=True)
class VolumeFitResult(FitResult):
    """The result of :func:`fit_volume`.

    Attributes
    ----------
    volume : Volume
        The fitted volume: densities (D, H, W) as per-sample opacities for the final
        ``n_pts_per_ray`` (PyTorch3D's convention) and RGB features (3, D, H, W), placed as the
        tutorial's (``voxel_size = volume_extent / volume_size``).
    n_active_voxels : int
        Voxels whose density was optimised at the final level (the dense recipe: all of them).
    n_colour_voxels : int
        Voxels whose colour was optimised at the final level.
    n_occupied_voxels : int
        Voxels of the final volume with non-zero density.
    samples_per_ray : float
        Mean number of samples marched per training ray at the final level (rays that miss
        every active voxel count as 0); the dense recipe marches those inside the grid's box.
    n_pts_per_ray : int
        Samples per ray of the renderer the volume is meant for.
    stages : list of dict
        Per level: grid size, image size, samples per ray, free voxels, rays and samples kept,
        solver status, iterations, seconds.
    view_losses : (N,) float64 or None
        geofit's methods: each training view's mean loss (colour + silhouette Huber) at the
        end; a view far above the others (reported in ``message``) disagrees with the rest:
        a wrong camera or a bad image.
    """

    volume: Volume | None = None
    n_active_voxels: int = 0
    n_colour_voxels: int = 0
    n_occupied_voxels: int = 0
    samples_per_ray: float = 0.0
    n_pts_per_ray: int = 0
    stages: list = field(default_factory=list)
    view_losses: np.ndarray | None = None

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d.update({"view_losses": None if self.view_losses is None else
                  [float(v) for v in self.view_losses]})
        d.update({"method": self.method, "n_active_voxels": self.n_active_voxels,
                  "n_colour_voxels": self.n_colour_voxels,
                  "n_occupied_voxels": self.n_occupied_voxels,
                  "samples_per_ray": self.samples_per_ray, "n_pts_per_ray": self.n_pts_per_ray,
                  "stages": self.stages})
        return d


# --------------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------------


def fit_volume(dataset, *args, recipe: str = "default", method: str | None = None,
               volume_size: int = 128, volume_extent: float = 3.0, n_pts_per_ray: int = 150,
               min_depth: float = 0.1, max_depth: float = 3.0, levels=None,
               iterations=None, carve: bool = True, carve_tolerance: int | None = None,
               carve_margin: float = 2.0,
               prune_threshold: float = 1e-3, prune_dilation: int = 2,
               termination: float | None = 1e-3, smoothness=0.03, huber_scaling: float = 0.1,
               lr: float = 0.1, batch_size: int = 10, n_iter: int = 300,
               time_budget: float | None = None, precision: str = "float32", seed=0,
               monitor: Callable[[Volume], dict] | None = None,
               monitor_every: float | None = None, verbose: bool = False,
               progress: bool = True) -> VolumeFitResult:
    """Fit a grid of densities and colours to posed images and silhouettes.

    Parameters
    ----------
    dataset : MultiViewDataset
        Target RGB images in [0, 1] with a black background (the tutorial's renders), target
        silhouettes in [0, 1] and the ``N`` cameras (PyTorch3D conventions).
    recipe : {"default", "tutorial"}
        ``"tutorial"``: PyTorch3D's recipe on the dense grid (Adam, ``n_iter`` steps of
        ``batch_size`` random views, lr x 0.1 at 75%). ``"default"``: geofit's reduced model
        (hull, coarse to fine, pruning, empty-space skipping).
    method : {"lbfgs", "lbfgs-nlopt", "adam"}, optional
        Solver of the default recipe: full-batch scipy L-BFGS (default), nlopt L-BFGS or Adam
        (lr ``lr``, x 0.1 for the last quarter of each level). The tutorial recipe is Adam.
    volume_size : int
        Final grid size (a cube, as the tutorial's 128).
    volume_extent : float
        World size of the grid's box; ``voxel_size = volume_extent / volume_size``.
    n_pts_per_ray, min_depth, max_depth
        The final renderer's ray sampling (150 samples over view depths [0.1, 3.0]).
    levels : sequence of int, optional
        Grid sizes of the coarse-to-fine levels, ending with ``volume_size`` (default: halving
        down to >= 32, e.g. (32, 64, 128)); ignored by ``"tutorial"``. The image size of a level
        is ``H * level / volume_size`` (rounded to a divisor of H and W) and its samples per ray
        ``n_pts_per_ray * level / volume_size``.
    iterations : int or sequence of int, optional
        Iteration budget per level (solver iterations for L-BFGS, steps for Adam); default
        (30, 30, 40) for L-BFGS and (50, 50, 50) for Adam, the last entry repeated for any
        further level.
    carve : bool
        Carve the visual hull (geofit's methods; the tutorial recipe never carves).
    carve_tolerance : int, optional
        Views allowed to disagree when carving (default 1 with 10 views or more, else 0).
    carve_margin : float
        Extra silhouette dilation for carving, in pixels (default 2: the tutorial's silhouettes
        are the mesh dilated by ~1.9 px in every image, which is not consistent in 3D near thin
        parts seen at different depths, so a tight hull would cut into what the views show).
    prune_threshold : float
        At each new level, voxels whose upsampled opacity per final-resolution sample is below
        this, and that are more than ``prune_dilation`` voxels from one above it, are fixed empty.
    prune_dilation : int
        See ``prune_threshold``.
    termination : float or None
        From the second level on, rays stop where the upsampled model's transmittance falls
        below this (None: march the whole range).
    smoothness : float or (2,) float
        Weights ``(lambda_density, lambda_colour)`` (one number: both) of a smoothness prior for
        geofit's methods: ``lambda (level / 64)^2`` times the mean squared difference between
        face-neighbouring free voxels of the densities and of the colours, so that it weighs the
        same squared gradient in world units at every level (0: none, the tutorial's
        objective; default 0.03). It fills what the views do not constrain (e.g. the top of
        the cow, never seen from elevation 0) smoothly instead of with stripes. Ignored by
        ``"tutorial"``.
    huber_scaling : float
        Scale of the Huber losses (0.1 as the tutorial).
    lr, batch_size, n_iter
        Adam settings (``batch_size`` and ``n_iter`` for the tutorial recipe).
    time_budget : float, optional
        Seconds of solver time for the whole fit (set-up work included).
    precision : {"float32", "float64"}
        Arithmetic of the sampled values, the raymarching and the sparse products (float32
        halves the memory traffic; the loss is summed and the parameters kept in float64).
    seed : int or numpy.random.Generator
        For the tutorial recipe's random view batches.
    monitor : callable, optional
        ``monitor(volume) -> dict`` of metrics, called with the clock paused at the end of
        every level, every ``monitor_every`` seconds of solver time, and at the end; the
        metrics go into the history's checkpoints.
    monitor_every : float, optional
        Seconds of solver time between monitor calls (None: levels and end only).
    verbose : bool
        Print one line per level.
    progress : bool
        Show a tqdm progress bar (on stderr; one tick per solver iteration).

    Returns
    -------
    VolumeFitResult
        Status ``"max_iter"``, ``"converged"``, ``"time_budget"``, ``"stalled"`` (the line
        search could not improve: usually converged to float precision), ``"diverged"`` or
        ``"nonfinite"`` (both return the best finite parameters), with the fitted volume, the
        history (loss, colour and silhouette terms), and the model size. The volume never holds
        NaN. A level that ends with ``"time_budget"``, ``"diverged"``, ``"nonfinite"`` or
        ``"failed"`` ends the fit: the volume is then that level's (coarser) grid, in the same
        world box.

    Raises
    ------
    ValueError
        On inconsistent shapes, non-finite inputs or invalid settings.
    """
    dataset = dataset_argument(dataset, args, fit="fit_volume")
    recipe, method = _recipe_and_method(recipe, method)
    o = _VolumeOptions(
        dataset.images, dataset.silhouettes, dataset.cameras, _grid_size(volume_size),
        check_positive(volume_extent, "volume_extent"),
        check_int(n_pts_per_ray, "n_pts_per_ray", 2),
        *_depths(min_depth, max_depth), method, check_positive(huber_scaling, "huber_scaling"),
        check_positive(lr, "lr"),
        None if time_budget is None else check_positive(time_budget, "time_budget"),
        _monitor(monitor), None if monitor_every is None else check_positive(
            monitor_every, "monitor_every"), bool(verbose), _precision(precision),
        bool(progress))
    if recipe == "tutorial":
        o.batch_size = check_int(batch_size, "batch_size")
        o.n_iter = check_int(n_iter, "n_iter")
        o.rng = as_rng(seed)
        with one_blas_thread():
            return VolumeFitResult(**_fit_tutorial(o))
    _level_options(o, levels=levels, iterations=iterations, carve=carve,
                   carve_tolerance=carve_tolerance, carve_margin=carve_margin,
                   prune_threshold=prune_threshold, prune_dilation=prune_dilation,
                   termination=termination, smoothness=smoothness)
    with one_blas_thread():
        return VolumeFitResult(**_LevelsFit(o).run())


def _grid_size(volume_size) -> int:
    from geofit._memory import check_allocation

    S = int(volume_size) if isinstance(volume_size, (numbers.Integral, np.integer)) else -1
    if S < 2 or isinstance(volume_size, bool):
        raise ValueError(f"volume_size: expected an integer >= 2, got {volume_size!r}")
    # memory guard (issue 18): 4 channels x 8 B x ~8 copies (values, gradients, Adam / L-BFGS
    # state, operators)
    check_allocation(4 * 8 * 8 * S**3, "volume_size", f"a {S}^3 grid (values, gradients, "
                     "solver state)")
    return S


def _depths(min_depth, max_depth) -> tuple[float, float]:
    min_depth, max_depth = float(min_depth), float(max_depth)
    if not (np.isfinite(min_depth) and np.isfinite(max_depth) and max_depth > min_depth):
        raise ValueError(f"max_depth: expected finite depths with max_depth > min_depth, got "
                         f"[{min_depth}, {max_depth}]")
    return min_depth, max_depth


def _monitor(monitor):
    if monitor is not None and not callable(monitor):
        raise TypeError(f"monitor: expected a callable, got {type(monitor)!r}")
    return monitor


def _precision(precision) -> np.dtype:
    check_choice(precision, "precision", ("float32", "float64"))
    return np.dtype(precision)


def _level_options(o: _VolumeOptions, *, levels, iterations, carve, carve_tolerance,
                   carve_margin, prune_threshold, prune_dilation, termination,
                   smoothness) -> None:
    """Check the settings of geofit's levels and store them in ``o``."""
    sm = np.atleast_1d(as_array(smoothness, "smoothness"))
    if sm.shape not in ((1,), (2,)) or np.any(sm < 0):
        raise ValueError(f"smoothness: expected one or two numbers >= 0, got {smoothness!r}")
    o.smoothness = (float(sm[0]), float(sm[-1]))
    o.prune_threshold = check_positive(prune_threshold, "prune_threshold", strict=False)
    o.prune_dilation = check_int(prune_dilation, "prune_dilation", 0)
    if termination is not None:
        termination = float(termination)
        if not 0.0 < termination < 1.0:
            raise ValueError(f"termination: expected a number in (0, 1) or None, got "
                             f"{termination!r}")
    o.termination = termination
    o.carve = bool(carve)
    o.carve_margin = check_positive(carve_margin, "carve_margin", strict=False)
    if carve_tolerance is None:
        carve_tolerance = 1 if len(o.imgs) >= 10 else 0
    o.carve_tolerance = check_int(carve_tolerance, "carve_tolerance", 0)
    S = o.S
    if levels is None:
        levels = [S]
        while levels[0] // 2 >= 32 and len(levels) < 3:
            levels.insert(0, levels[0] // 2)
    levels = [int(v) for v in levels]
    if not levels or levels[-1] != S or any(v < 2 for v in levels) or \
            any(b <= a for a, b in zip(levels, levels[1:])):
        raise ValueError(f"levels: expected increasing grid sizes >= 2 ending with volume_size "
                         f"= {S}, got {levels}")
    default_iters = (30, 30, 40) if o.method != "adam" else (50, 50, 50)
    if iterations is None:
        iterations = default_iters[:len(levels)] if len(levels) <= 3 else \
            tuple(default_iters) + (default_iters[-1],) * (len(levels) - 3)
    elif isinstance(iterations, (numbers.Integral, np.integer)):
        iterations = (int(iterations),) * len(levels)
    iterations = [int(v) for v in iterations]
    if len(iterations) < len(levels):
        iterations += [iterations[-1]] * (len(levels) - len(iterations))
    if any(v < 1 for v in iterations):
        raise ValueError(f"iterations: expected integers >= 1, got {iterations}")
    o.levels, o.iterations = levels, iterations


def _recipe_and_method(recipe, method) -> tuple[str, str]:
    """The recipe and method of :func:`fit_volume` (the former ``method="tutorial"`` is the
    tutorial recipe, with a DeprecationWarning)."""
    if method == "tutorial":
        warn_deprecated("fit_volume(method='tutorial')", "fit_volume(dataset, recipe='tutorial')",
                        5)
        recipe, method = "tutorial", None
    recipe = recipe_name(recipe, RECIPES, fit="fit_volume")
    method = method_name(RECIPES[recipe]["method"] if method is None else method, "method",
                         FIT_VOLUME_METHODS, fit="fit_volume", stacklevel=5)
    if recipe == "tutorial" and method != "adam":
        raise ValueError(f"method: the tutorial recipe is Adam's; got method={method!r}")
    return recipe, method


