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

from .._memory import check_allocation
from .._threads import one_blas_thread
from .._validate import as_array, as_rng, check_choice, check_positive
from ..cameras import CamerasBase
from ..structures import MultiViewDataset
from ..loss.robust import huber
from ..metrics import psnr as image_psnr
from ..render.volume import VolumeRenderer
from ..render.volume.raymarching import EmissionAbsorptionRaymarcher
from ..render.volume.raysampling import NDCMultinomialRaysampler
from ..structures.volume import Volume, visual_hull
from ._options import as_dataset, check_int, merge_options, recipe_name
from ._volume_levels import _fit_tutorial, _Plan, _Solver
from .history import FitResult
from .solvers import StepInfo

__all__ = [
    "FIT_VOLUME_METHODS",
    "RECIPES",
    "VolumeFitOptions",
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
        a wrong camera or a bad image. None when the time budget ran out (the diagnostic costs
        one more evaluation).
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


@dataclass(frozen=True)
class VolumeFitOptions:
    """The settings of :func:`fit_volume`; None means "the recipe's".

    Attributes
    ----------
    method : {"lbfgs", "lbfgs-nlopt", "adam"}
        Solver of the default recipe: full-batch scipy L-BFGS (default), nlopt L-BFGS or Adam
        (lr ``lr``, x 0.1 for the last quarter of each level). The tutorial recipe is Adam.
    volume_size : int
        Final grid size (a cube, as the tutorial's 128).
    volume_extent : float
        World size of the grid's box (3.0); ``voxel_size = volume_extent / volume_size``.
    n_pts_per_ray, min_depth, max_depth
        The final renderer's ray sampling (150 samples over view depths [0.1, 3.0]).
    levels : sequence of int
        Grid sizes of the coarse-to-fine levels, ending with ``volume_size`` (default: halving
        down to >= 32, e.g. (32, 64, 128)); ignored by ``"tutorial"``. The image size of a level
        is ``H * level / volume_size`` (rounded to a divisor of H and W) and its samples per ray
        ``n_pts_per_ray * level / volume_size``.
    iterations : int or sequence of int
        Iteration budget per level (solver iterations for L-BFGS, steps for Adam); default
        (30, 30, 40) for L-BFGS and (50, 50, 50) for Adam, the last entry repeated for any
        further level.
    carve : bool
        Carve the visual hull (True; the tutorial recipe never carves).
    carve_tolerance : int
        Views allowed to disagree when carving (default 1 with 10 views or more, else 0).
    carve_margin : float
        Extra silhouette dilation for carving, in pixels (2: the tutorial's silhouettes are the
        mesh dilated by ~1.9 px in every image, which is not consistent in 3D near thin parts
        seen at different depths, so a tight hull would cut into what the views show).
    prune_threshold, prune_dilation : float, int
        At each new level, voxels whose upsampled opacity per final-resolution sample is below
        ``prune_threshold`` (1e-3), and that are more than ``prune_dilation`` (2) voxels from
        one above it, are fixed empty.
    termination : float
        From the second level on, rays stop where the upsampled model's transmittance falls
        below this (1e-3; 0: march the whole range).
    smoothness : float or (2,) float
        Weights ``(lambda_density, lambda_colour)`` (one number: both; 0.03) of a smoothness
        prior for geofit's methods: ``lambda (level / 64)^2`` times the mean squared difference
        between face-neighbouring free voxels of the densities and of the colours (0: none,
        the tutorial's objective). It fills what the views do not constrain (e.g. the top of
        the cow, never seen from elevation 0) smoothly instead of with stripes.
    huber_scaling : float
        Scale of the Huber losses (0.1 as the tutorial).
    lr, batch_size, n_iter
        Adam settings (0.1; ``batch_size`` 10 and ``n_iter`` 300 for the tutorial recipe).
    precision : {"float32", "float64"}
        Arithmetic of the sampled values, the raymarching and the sparse products (float32
        halves the memory traffic; the loss is summed and the parameters kept in float64).
    """

    method: str | None = None
    volume_size: int | None = None
    volume_extent: float | None = None
    n_pts_per_ray: int | None = None
    min_depth: float | None = None
    max_depth: float | None = None
    levels: Any = None
    iterations: Any = None
    carve: bool | None = None
    carve_tolerance: int | None = None
    carve_margin: float | None = None
    prune_threshold: float | None = None
    prune_dilation: int | None = None
    termination: float | None = None
    smoothness: Any = None
    huber_scaling: float | None = None
    lr: float | None = None
    batch_size: int | None = None
    n_iter: int | None = None
    precision: str | None = None


_COMMON = dict(volume_size=128, volume_extent=3.0, n_pts_per_ray=150, min_depth=0.1,
               max_depth=3.0, carve=True, carve_margin=2.0, prune_threshold=1e-3,
               prune_dilation=2, termination=1e-3, smoothness=0.03, huber_scaling=0.1, lr=0.1,
               batch_size=10, n_iter=300, precision="float32")

#: Recipes of :func:`fit_volume` (presets of :class:`VolumeFitOptions`): geofit's reduced model
#: (hull, coarse to fine, pruning, empty-space skipping; L-BFGS), or the tutorial's dense grid
#: and Adam (``n_iter`` steps of ``batch_size`` random views, lr x 0.1 at 75%).
RECIPES: dict[str, VolumeFitOptions] = {
    "default": VolumeFitOptions(method="lbfgs", **_COMMON),
    "tutorial": VolumeFitOptions(method="adam", **_COMMON),
}


def fit_volume(dataset, *, recipe: str = "default", options: VolumeFitOptions | None = None,
               time_budget: float | None = None, seed=0,
               evaluator: Callable[[Volume], dict] | None = None,
               eval_every: int | None = None,
               callback: Callable[[StepInfo], bool | None] | None = None,
               progress: bool = True) -> VolumeFitResult:
    """Fit a grid of densities and colours to posed images and silhouettes.

    Parameters
    ----------
    dataset : MultiViewDataset
        Target RGB images in [0, 1] with a black background (the tutorial's renders), target
        silhouettes in [0, 1] and the ``N`` cameras (PyTorch3D conventions).
    recipe : {"default", "tutorial"}
        Named settings (:data:`RECIPES`): ``"default"``, geofit's reduced model (hull, coarse
        to fine, pruning, empty-space skipping, L-BFGS); ``"tutorial"``, PyTorch3D's recipe on
        the dense grid (Adam, ``n_iter`` steps of ``batch_size`` random views, lr x 0.1 at
        75%).
    options : VolumeFitOptions, optional
        Settings that override the recipe's (every field left None keeps the recipe's).
    time_budget : float, optional
        Wall-clock seconds for the whole fit, its set-up included (not the time spent in the
        evaluator or callback you pass); checked inside each evaluation, between view chunks.
    seed : int or numpy.random.Generator
        For the tutorial recipe's random view batches.
    evaluator : callable, optional
        ``evaluator(volume) -> dict`` of metrics, called with the clock paused at the end of
        every level, every ``eval_every`` steps, and at the end; the metrics go into the
        history's checkpoints.
    eval_every : int, optional
        Steps between checkpoints (None: levels and end only).
    callback : callable, optional
        ``callback(StepInfo) -> bool | None`` after each step (``info.stage`` the level,
        ``info.terms`` the loss terms); True stops the fit with status ``"callback"``.
    progress : bool
        Show a tqdm progress bar (on stderr; one tick per solver iteration).

    Returns
    -------
    VolumeFitResult
        Status ``"max_iter"``, ``"converged"``, ``"time_budget"``, ``"stalled"`` (the line
        search could not improve: usually converged to float precision), ``"diverged"`` or
        ``"nonfinite"`` (both return the best finite parameters), with the fitted volume, the
        history (loss, colour and silhouette terms), and the model size. The volume never holds
        NaN. A level that ends with ``"time_budget"``, ``"diverged"``, ``"nonfinite"``,
        ``"callback"`` or ``"failed"`` ends the fit: the volume is then that level's (coarser)
        grid, in the same world box.

    Raises
    ------
    ValueError
        On inconsistent shapes, non-finite inputs or invalid settings.
    """
    dataset = _as_dataset(dataset)
    plan = _plan(dataset, recipe, options, time_budget=time_budget, evaluator=evaluator,
                 eval_every=eval_every, callback=callback, progress=progress)
    if recipe == "tutorial":
        plan.rng = as_rng(seed)
        with one_blas_thread():
            return VolumeFitResult(**_fit_tutorial(plan))
    with one_blas_thread():
        return VolumeFitResult(**_Solver(plan).run())


def _as_dataset(dataset) -> MultiViewDataset:
    """The training views, checked once at the door (RGB images needed; unknown silhouettes
    fitted as full)."""
    return as_dataset(dataset, fit="fit_volume", silhouettes="full")


def _plan(dataset: MultiViewDataset, recipe, options, *, time_budget, evaluator, eval_every,
          callback, progress) -> _Plan:
    """Check every setting once and fill in the recipe's."""
    recipe = recipe_name(recipe, RECIPES, fit="fit_volume")
    o = merge_options(RECIPES[recipe], options, VolumeFitOptions, "options")
    check_choice(o.method, "options.method", FIT_VOLUME_METHODS)
    if recipe == "tutorial" and o.method != "adam":
        raise ValueError(f"options.method: the tutorial recipe is Adam's; got {o.method!r}")
    if evaluator is not None and not callable(evaluator):
        raise TypeError(f"evaluator: expected a callable (volume) -> dict, got "
                        f"{type(evaluator)!r}")
    if callback is not None and not callable(callback):
        raise TypeError(f"callback: expected a callable, got {type(callback)!r}")
    plan = _Plan(
        dataset.images, dataset.silhouettes, dataset.cameras, _grid_size(o.volume_size),
        check_positive(o.volume_extent, "volume_extent"),
        check_int(o.n_pts_per_ray, "n_pts_per_ray", 2),
        *_depths(o.min_depth, o.max_depth), o.method,
        check_positive(o.huber_scaling, "huber_scaling"), check_positive(o.lr, "lr"),
        None if time_budget is None else check_positive(time_budget, "time_budget"),
        evaluator, None if eval_every is None else check_int(eval_every, "eval_every"),
        callback, _precision(o.precision), bool(progress))
    if recipe == "tutorial":
        plan.batch_size = check_int(o.batch_size, "batch_size")
        plan.n_iter = check_int(o.n_iter, "n_iter")
        return plan
    _level_options(plan, levels=o.levels, iterations=o.iterations, carve=o.carve,
                   carve_tolerance=o.carve_tolerance, carve_margin=o.carve_margin,
                   prune_threshold=o.prune_threshold, prune_dilation=o.prune_dilation,
                   termination=o.termination or None, smoothness=o.smoothness)
    return plan


def _grid_size(volume_size) -> int:
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


def _precision(precision) -> np.dtype:
    check_choice(precision, "precision", ("float32", "float64"))
    return np.dtype(precision)


def _level_options(o: _Plan, *, levels, iterations, carve, carve_tolerance,
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
