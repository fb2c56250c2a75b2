"""Fit a neural radiance field to posed images (PyTorch3D's sixth tutorial), on the CPU.

The tutorial (``fit_simple_neural_radiance_field``) fits :class:`NeuralRadianceField` (60
frequencies, two hidden layers of 256 with Softplus(beta=10), 317,188 parameters) to 40 views of
the cow: per step 6 random views, 750 Monte Carlo rays per view with 128 samples each over view
depths [0.1, 3.0], Huber losses (scale 0.1) on the colours and the silhouettes (targets sampled
bilinearly at the rays' xy), Adam with lr 1e-3 for 3000 steps and a new Adam at lr 1e-4 from 75 %.
:func:`fit_nerf` with ``recipe="tutorial"`` runs exactly that recipe, with the gradients of
:mod:`geofit.render.volume` (pixels -> raymarcher vjp -> density and colour heads -> trunk).

geofit's scene-sized recipe (``recipe="default"``) fits the same kind of field but models no more
than the scene needs:

* **a smaller network**: 8 frequencies from ``omega0 = 1``, ReLU layers of 96, a colour head of
  48 with one direction frequency (the cow at 128 px needs nothing finer; the lighting is
  nearly view-independent, and a smooth dependence on the direction extrapolates better to
  elevations the training views do not cover);
* **small steps**: 8 views x 128 rays per step (1024 rays): on a CPU many cheap steps beat few
  large ones (measured: the same held-out PSNR in about half the time of 4096-ray steps);
* **silhouettes as the data define them**: the tutorial's silhouettes are about 2 px wider than
  the object's coverage in the images (the soft silhouette above 1e-4), so the silhouette loss
  is left out in a 2 px band inside each silhouette's edge, where the images say "background";
  fitting both there grows an opaque black shell around the object, dark from above;
* **visual hull**: samples outside the voxels whose centre projects into every (dilated)
  training silhouette are skipped (their density is exactly 0), and so are the rays that miss the
  hull: their render is exactly the black background, so they carry no gradient. Training rays
  are drawn among the pixels whose ray meets the hull (importance sampling of rays) at pixel
  centres, so targets are exact pixel values;
* **coarse density grid**: every ``density_grid_every`` steps the network is evaluated at one
  random point in each hull voxel; voxels whose opacity stays below ``density_threshold`` are
  skipped too, and samples lying more than ``occlusion_margin`` samples behind the point where
  the grid's transmittance falls below ``min_transmittance`` are not evaluated (they would add
  less than that to the pixel);
* **threads**: each step's rays are split into chunks that run forward and backward on
  geofit's thread pool (:func:`geofit.get_num_threads` threads, one BLAS thread each; numpy
  releases the GIL), in float32 arithmetic;
* **a time-aware schedule**: with a time budget the learning rate decays exponentially with the
  elapsed fraction of the budget.

Every result reports its parameter count (``n_params``) and the mean number of samples evaluated
per ray (``samples_per_ray``, 128 for the tutorial). Held-out views, if given, are rendered in full
at checkpoints (PSNR and the tutorial's Huber loss), optionally stopping the fit when the held-out
loss stops improving; the final full-image renders of the held-out views are returned.

Notes
-----
The gradient is exact for the rendered function: which samples a ray keeps, which voxels are
occupied and which rays are drawn are piecewise-constant choices that do not depend on the weights
(the density grid is refreshed from the network between steps, not differentiated).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from .._memory import check_mlp_size
from .._threads import get_num_threads, parallel_map
from .._validate import as_array, as_rng, as_unit_images, check_choice, check_positive
from ..cameras import CamerasBase
from ..loss.robust import huber
from ..render.volume import (
    EmissionAbsorptionRaymarcher,
    ImplicitRenderer,
    NDCMultinomialRaysampler,
    NeuralRadianceField,
    OccupancyGrid,
    RayBundle,
)
from ._nerf_train import _NerfTraining
from ._options import Recipes, dataset_argument, method_name, recipe_name, warn_deprecated
from .history import Clock, FitResult

__all__ = [
    "NERF_PRESETS",
    "RECIPES",
    "NerfConfig",
    "NerfFitResult",
    "fit_nerf",
    "huber",
    "render_nerf",
    "sample_images_at_xys",
]

#: Recipes of :func:`fit_nerf`: geofit's scene-sized field, or the tutorial's.
RECIPES: dict[str, dict] = Recipes({"default": {"method": "adam", "config": "NerfConfig.scene"},
                                    "tutorial": {"method": "adam",
                                                 "config": "NerfConfig.tutorial"}},
                                   fit="fit_nerf")

#: Deprecated: the former ``preset`` names (``"scene"`` is the recipe ``"default"``).
NERF_PRESETS = ("scene", "tutorial")


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------


@dataclass
class NerfConfig:
    """Every setting of :func:`fit_nerf`; :meth:`tutorial` and :meth:`scene` are the recipes.

    Network (see :class:`~geofit.render.NeuralRadianceField`): ``n_harmonic_functions``,
    ``omega0``, ``append_input``, ``n_hidden_neurons``, ``n_hidden_layers``,
    ``n_harmonic_functions_dir``, ``omega0_dir``, ``n_hidden_color``, ``activation``, ``beta``.

    Rays: ``ray_sampling`` is ``"montecarlo"`` (the tutorial: xy uniform in NDC [-1, 1]^2, targets
    sampled bilinearly at ``-xys`` with align_corners=True) or ``"pixels"`` (pixel centres among
    those whose ray meets the occupancy grid); ``batch_size`` views per step,
    ``n_rays_per_image`` rays per view, ``n_pts_per_ray`` samples over view depths
    [``min_depth``, ``max_depth``], ``stratified`` jitters them within their bins.

    Skipping: ``occupancy`` is ``"none"`` (evaluate every sample), ``"hull"`` (visual hull at
    ``hull_resolution``^3 over ``bounds``, silhouettes dilated by ``hull_dilate_pixels``) or
    ``"density"`` (the hull refined by a coarse density grid refreshed every
    ``density_grid_every`` steps after ``density_grid_warmup`` steps, with
    ``density_threshold``, ``min_transmittance`` and ``occlusion_margin``).

    Optimisation: ``n_iter`` Adam steps at ``lr``; ``lr_schedule`` ``"step"`` (times
    ``lr_decay_factor`` at ``lr_decay_at`` of the run, Adam restarted as in the tutorial) or
    ``"exponential"`` (down to ``lr * lr_decay_factor`` at the end of the run, measured in steps
    or in the time budget, whichever is further along); ``huber_scale`` of the losses;
    ``opacity_regularization`` weights a per-ray sum of ``alpha (1 - alpha)`` over the evaluated
    samples (0 in the tutorial; with a density grid it starts after the grid's warm-up), which
    pushes each sample's opacity to 0 or 1: surfaces instead of fog, which matters for views
    from elevations the training views do not cover. ``silhouette_margin`` (pixels, ``"pixels"``
    sampling only) leaves the silhouette loss out in a band that wide just inside each
    silhouette's edge: the tutorial's silhouettes are the soft silhouette above 1e-4, about
    2 px wider than the object's coverage in the RGB images, and fitting both makes an opaque
    black shell around the object, invisible from the training elevation but dark from above.

    Execution: ``dtype`` of the network, ``n_threads`` (None: :func:`geofit.get_num_threads`),
    ``chunk_rays`` for the full-image renders.
    """

    n_harmonic_functions: int = 60
    omega0: float = 0.1
    append_input: bool = False
    n_hidden_neurons: int = 256
    n_hidden_layers: int = 2
    n_harmonic_functions_dir: int | None = None
    omega0_dir: float | None = None
    n_hidden_color: int | None = None
    activation: str = "softplus"
    beta: float = 10.0
    ray_sampling: str = "montecarlo"
    batch_size: int = 6
    n_rays_per_image: int = 750
    n_pts_per_ray: int = 128
    min_depth: float = 0.1
    max_depth: float = 3.0
    stratified: bool = False
    occupancy: str = "none"
    hull_resolution: int = 96
    hull_dilate_pixels: int = 2
    bounds: tuple = ((-1.25, -1.25, -1.25), (1.25, 1.25, 1.25))
    density_grid_every: int = 16
    density_grid_warmup: int = 100
    density_threshold: float = 0.01
    min_transmittance: float = 1e-3
    occlusion_margin: int = 3
    n_iter: int = 3000
    lr: float = 1e-3
    lr_schedule: str = "step"
    lr_decay_at: float = 0.75
    lr_decay_factor: float = 0.1
    huber_scale: float = 0.1
    opacity_regularization: float = 0.0
    silhouette_margin: int = 0
    dtype: str = "float32"
    n_threads: int | None = None
    chunk_rays: int = 4096

    @classmethod
    def tutorial(cls, **overrides) -> NerfConfig:
        """The tutorial's recipe (the defaults), with ``overrides``."""
        return replace(cls(), **overrides)

    @classmethod
    def scene(cls, **overrides) -> NerfConfig:
        """geofit's scene-sized recipe, with ``overrides``."""
        base = cls(
            n_harmonic_functions=8, omega0=1.0, append_input=True, n_hidden_neurons=96,
            n_hidden_layers=2, n_harmonic_functions_dir=1, omega0_dir=1.0, n_hidden_color=48,
            activation="relu", ray_sampling="pixels", batch_size=8, n_rays_per_image=128,
            n_pts_per_ray=128, stratified=True, occupancy="density", density_grid_every=64,
            density_grid_warmup=400, n_iter=100000, lr=5e-3, lr_schedule="exponential",
            lr_decay_factor=0.1, silhouette_margin=2)
        return replace(base, **overrides)

    def network(self, seed=0) -> NeuralRadianceField:
        """A freshly initialised network of this configuration."""
        return NeuralRadianceField(
            self.n_harmonic_functions, self.n_hidden_neurons,
            n_hidden_layers=self.n_hidden_layers, omega0=self.omega0,
            append_input=self.append_input, n_harmonic_functions_dir=self.n_harmonic_functions_dir,
            omega0_dir=self.omega0_dir, n_hidden_color=self.n_hidden_color,
            activation=self.activation, beta=self.beta, seed=seed, dtype=self.dtype)

    def validate(self) -> NerfConfig:
        """Check every field; returns self."""
        check_choice(self.ray_sampling, "ray_sampling", ("montecarlo", "pixels"))
        check_choice(self.occupancy, "occupancy", ("none", "hull", "density"))
        check_choice(self.lr_schedule, "lr_schedule", ("step", "exponential"))
        check_choice(self.activation, "activation", ("softplus", "relu"))
        check_choice(str(np.dtype(self.dtype)), "dtype", ("float32", "float64"))
        for name in ("batch_size", "n_rays_per_image", "n_pts_per_ray", "n_iter",
                     "hull_resolution", "density_grid_every", "chunk_rays",
                     "n_harmonic_functions", "n_hidden_neurons", "n_hidden_layers"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {v!r}")
        check_mlp_size(self.n_hidden_neurons, self.n_hidden_layers)  # before building it
        for name in ("hull_dilate_pixels", "density_grid_warmup", "occlusion_margin",
                     "silhouette_margin"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 0:
                raise ValueError(f"{name}: expected an integer >= 0, got {v!r}")
        for name in ("lr", "huber_scale", "lr_decay_factor", "omega0", "beta"):
            check_positive(getattr(self, name), name)
        check_positive(self.opacity_regularization, "opacity_regularization", strict=False)
        for name in ("density_threshold", "min_transmittance"):
            v = check_positive(getattr(self, name), name, strict=False)
            if v >= 1:
                raise ValueError(f"{name}: expected a number in [0, 1), got {v!r}")
        if not 0.0 <= float(self.lr_decay_at) <= 1.0:
            raise ValueError(f"lr_decay_at: expected a fraction in [0, 1], got "
                             f"{self.lr_decay_at!r}")
        if not 0 <= float(self.min_depth) < float(self.max_depth):
            raise ValueError(f"max_depth: expected 0 <= min_depth < max_depth, got "
                             f"{self.min_depth!r}, {self.max_depth!r}")
        if self.n_threads is not None and (not isinstance(self.n_threads, (int, np.integer))
                                           or self.n_threads < 1):
            raise ValueError(f"n_threads: expected None or an integer >= 1, got "
                             f"{self.n_threads!r}")
        as_array(self.bounds, "bounds", (2, 3))
        if self.ray_sampling == "pixels" and self.occupancy == "none":
            raise ValueError("ray_sampling: 'pixels' draws rays among the pixels that meet the "
                             "occupancy grid; use occupancy='hull' or 'density'")
        return self


# --------------------------------------------------------------------------------------------
# Target sampling (the tutorial's sample_images_at_mc_locs)
# --------------------------------------------------------------------------------------------


def sample_images_at_xys(images, xys) -> np.ndarray:
    """The tutorial's ``sample_images_at_mc_locs``: bilinear samples at NDC ``xys``.

    ``grid_sample(images, -xys, align_corners=True)`` with zero padding: image column ``u =
    (1 - x) (W - 1) / 2`` and row ``v = (1 - y) (H - 1) / 2``.

    Parameters
    ----------
    images : (B, H, W, C) float64
    xys : (B, ..., 2) float64

    Returns
    -------
    samples : (B, ..., C) float64
    """
    im = as_array(images, "images", (None, None, None, None))
    xy = as_array(xys, "xys")
    if xy.ndim < 2 or xy.shape[0] != im.shape[0] or xy.shape[-1] != 2:
        raise ValueError(f"xys: expected shape ({im.shape[0]}, ..., 2), got {xy.shape}")
    B, H, W, C = im.shape
    lead = xy.shape[1:-1]
    flat = xy.reshape(B, -1, 2)
    u = (1.0 - flat[..., 0]) * (W - 1) / 2.0
    v = (1.0 - flat[..., 1]) * (H - 1) / 2.0
    u0 = np.floor(u)
    v0 = np.floor(v)
    fu, fv = u - u0, v - v0
    out = np.zeros(flat.shape[:2] + (C,))
    b = np.arange(B)[:, None]
    for du, dv, w in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)),
                      (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):  # the four corners
        uu = (u0 + du).astype(np.int64)
        vv = (v0 + dv).astype(np.int64)
        ok = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
        val = im[b, np.clip(vv, 0, H - 1), np.clip(uu, 0, W - 1)]
        out += (w * ok)[..., None] * val
    return out.reshape((B,) + lead + (C,))


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------


@dataclass(kw_only=True)
class NerfFitResult(FitResult):
    """The result of :func:`fit_nerf`.

    Attributes
    ----------
    field : NeuralRadianceField
        The fitted network (the best held-out checkpoint when early stopping was asked for).
    config : NerfConfig
        The settings used.
    occupancy : OccupancyGrid or None
        The visual hull used for skipping and for the renders (None for ``occupancy="none"``).
    samples_per_ray : float
        Mean number of samples evaluated per training ray (the tutorial: ``n_pts_per_ray``).
    psnr : float or None
        PSNR of the final held-out renders (None without held-out views).
    images : (N, H, W, 4) float64 or None
        Full-image renders (RGB, opacity) of the held-out views with the final field.
    wall_seconds : float
        Wall time of the whole call, checkpoints and final renders included.
    """

    field: NeuralRadianceField
    config: NerfConfig
    occupancy: OccupancyGrid | None = None
    samples_per_ray: float = 0.0
    psnr: float | None = None
    images: np.ndarray | None = None
    wall_seconds: float = 0.0

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d.update({"samples_per_ray": self.samples_per_ray, "psnr": self.psnr,
                  "wall_seconds": self.wall_seconds, "config": asdict(self.config)})
        return d


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


def render_nerf(field: NeuralRadianceField, cameras: CamerasBase, image_size=128, *,
                n_pts_per_ray: int = 128, min_depth: float = 0.1, max_depth: float = 3.0,
                occupancy: OccupancyGrid | None = None, chunk_rays: int = 4096,
                n_threads: int | None = None) -> np.ndarray:
    """Full-image renders of a field (the tutorial's grid renderer).

    Parameters
    ----------
    field : NeuralRadianceField
    cameras : CamerasBase
        ``N`` cameras.
    image_size : int or (H, W)
        Output size.
    n_pts_per_ray, min_depth, max_depth
        The ``NDCMultinomialRaysampler`` settings (the field was trained with them).
    occupancy : OccupancyGrid, optional
        Skip samples outside it (exactly the render of the field with density 0 outside).
    chunk_rays : int
        Rays per chunk (bounds memory).
    n_threads : int, optional
        Threads over chunks (None: :func:`geofit.get_num_threads`).

    Returns
    -------
    images : (N, H, W, 4) float64
        RGB and opacity.
    """
    if not isinstance(field, NeuralRadianceField):
        raise TypeError(f"field: expected a NeuralRadianceField, got {type(field)!r}")
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit cameras batch, got {type(cameras)!r}")
    H, W = (image_size, image_size) if np.isscalar(image_size) else map(int, image_size)
    sampler = NDCMultinomialRaysampler(image_width=int(W), image_height=int(H),
                                       n_pts_per_ray=n_pts_per_ray, min_depth=min_depth,
                                       max_depth=max_depth)
    renderer = ImplicitRenderer(sampler, EmissionAbsorptionRaymarcher(), occupancy=occupancy)
    n_threads = get_num_threads() if n_threads is None else max(int(n_threads), 1)
    r = len(cameras) * int(H) * int(W)
    from geofit._memory import check_allocation  # memory guard (issue 18), measured ~7
    per = 7 * np.dtype(field.dtype).itemsize * field.config["n_hidden_neurons"]  # B/sample
    check_allocation(per * min(chunk_rays, r) * n_pts_per_ray * n_threads, "chunk_rays and "
                     "n_pts_per_ray", "the network activations of one chunk of rays per thread")
    bundle = sampler(cameras)
    flat = RayBundle(*(np.asarray(a).reshape(-1, a.shape[-1]) for a in bundle))
    r = flat.origins.shape[0]
    chunks = [slice(s, min(s + chunk_rays, r)) for s in range(0, r, chunk_rays)]

    def work(sl):
        return renderer._render_flat(RayBundle(*(a[sl] for a in flat)), field, cache=False)[0]

    out = np.concatenate(parallel_map(work, chunks, n_threads), axis=0)
    return out.reshape(len(cameras), int(H), int(W), 4)


# --------------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------------


class _Data:
    """Validated training / held-out data."""

    def __init__(self, images, silhouettes, cameras, name: str):
        self.images = as_unit_images(images, f"{name}images", (None, None, None, 3))
        N, H, W, _ = self.images.shape
        if N == 0:
            raise ValueError(f"{name}images: expected at least one view, got shape "
                             f"{self.images.shape}")
        self.silhouettes = as_array(silhouettes, f"{name}silhouettes", (N, H, W))
        if not isinstance(cameras, CamerasBase):
            raise TypeError(f"{name}cameras: expected a geofit cameras batch, got "
                            f"{type(cameras)!r}")
        if len(cameras) != N:
            raise ValueError(f"{name}cameras: expected {N} cameras (one per image), got "
                             f"{len(cameras)}")
        self.cameras = cameras
        self.N, self.H, self.W = N, H, W


def _held_out(held_out) -> _Data | None:
    if held_out is None or held_out is False:
        return None
    if hasattr(held_out, "images") and hasattr(held_out, "cameras"):
        return _Data(held_out.images, held_out.silhouettes, held_out.cameras, "held_out.")
    try:
        images, silhouettes, cameras = held_out
    except (TypeError, ValueError):
        raise ValueError("held_out: expected (images, silhouettes, cameras) or an object with "
                         "those attributes") from None
    return _Data(images, silhouettes, cameras, "held_out.")


def _recipe(recipe: str, preset: str | None) -> str:
    """The recipe of :func:`fit_nerf` (the former ``preset=`` warns)."""
    if preset is not None:
        check_choice(preset, "preset", NERF_PRESETS)
        new = "default" if preset == "scene" else "tutorial"
        warn_deprecated(f"fit_nerf(preset={preset!r})", f"fit_nerf(dataset, recipe={new!r})", 5)
        recipe = new
    return recipe_name(recipe, RECIPES, fit="fit_nerf")


def fit_nerf(dataset, *args, recipe: str = "default", method: str | None = None,
             config: NerfConfig | None = None, held_out=None, time_budget: float | None = None,
             eval_every: float | None = None, early_stopping: int | None = None,
             render_size: int | None = None, init: NeuralRadianceField | None = None, seed=0,
             callback: Callable[[dict], bool | None] | None = None, verbose: bool = False,
             preset: str | None = None, progress: bool = True,
             **overrides) -> NerfFitResult:
    """Fit a neural radiance field to posed RGB images and silhouettes.

    Parameters
    ----------
    dataset : MultiViewDataset
        Training images in [0, 1] (black background, as the tutorial's renders), silhouettes
        in [0, 1] and the ``N`` cameras; ``dataset.held_out`` is the default ``held_out``.
    recipe : {"default", "tutorial"}
        Base settings: geofit's scene-sized recipe (:meth:`NerfConfig.scene`) or the tutorial's
        (:meth:`NerfConfig.tutorial`).
    method : {"adam"}, optional
        The solver (Adam is the only one: the objective is stochastic).
    config : NerfConfig, optional
        Settings to use instead of the recipe's.
    held_out : MultiViewDataset, (images, silhouettes, cameras), None or False
        Views not trained on: rendered in full at checkpoints (PSNR and Huber loss) and at the
        end. None: ``dataset.held_out``; False: none.
    time_budget : float, optional
        Seconds of solver time (checkpoints excluded); the fit stops with status
        ``"time_budget"`` when used up.
    eval_every : float, optional
        Checkpoint interval: seconds of solver time if ``time_budget`` is set, else steps
        (default: 1/20 of the budget or of ``n_iter``).
    early_stopping : int, optional
        Stop (status ``"converged"``) when the held-out loss has not improved for this many
        checkpoints, and return the best checkpoint's field.
    render_size : int, optional
        Size of the final held-out renders (default: the held-out images' size).
    init : NeuralRadianceField, optional
        Start from a copy of this network (its architecture replaces the configuration's);
        the density grid starts from the visual hull as usual.
    seed : int or numpy.random.Generator
        Initialisation, view and ray choices.
    callback : callable, optional
        ``callback(info: dict) -> bool | None`` at each checkpoint (``step``, ``seconds``,
        ``loss``, and the held-out metrics); True stops the fit (status ``"callback"``).
    verbose : bool
        Print a line per checkpoint.
    progress : bool
        Show a tqdm progress bar (on stderr; steps, or seconds of the time budget).
    preset : {"scene", "tutorial"}, optional
        Deprecated: ``recipe`` (``"scene"`` is ``"default"``).
    **overrides
        Fields of :class:`NerfConfig` replacing the recipe's.

    Returns
    -------
    NerfFitResult
        Status ``"max_iter"``, ``"time_budget"``, ``"converged"`` (early stopping),
        ``"callback"``, ``"nonfinite"`` when a loss or gradient became NaN or inf (the last
        finite parameters are returned, never NaN), or ``"diverged"`` when, with held-out views,
        the final held-out loss is no better than the untrained network's (a learning rate far
        too large kills the network rather than making it NaN).
    """
    t_wall = time.perf_counter()
    data = dataset_argument(dataset, args, fit="fit_nerf")
    if held_out is None:
        held_out = data.held_out
    recipe = _recipe(recipe, preset)
    method = method_name("adam" if method is None else method, "method", ("adam",),
                         fit="fit_nerf")
    cfg = _config(recipe, config, overrides)
    data = _Data(data.images, data.silhouettes, data.cameras, "")
    test = _held_out(held_out)
    if time_budget is not None:
        time_budget = check_positive(time_budget, "time_budget")
    if eval_every is not None:
        eval_every = check_positive(eval_every, "eval_every")
    if early_stopping is not None:
        if test is None:
            raise ValueError("early_stopping: needs held_out views")
        if not isinstance(early_stopping, (int, np.integer)) or early_stopping < 1:
            raise ValueError(f"early_stopping: expected an integer >= 1, got {early_stopping!r}")
    rng = as_rng(seed)
    clock = Clock()  # the set-up (hull, rays) is part of the method's time
    n_threads = get_num_threads() if cfg.n_threads is None else int(cfg.n_threads)
    field, cfg = _initial_field(init, cfg, rng)
    _check_step_memory(cfg, data.N, n_threads)
    training = _NerfTraining(cfg, data, test, field, rng=rng, clock=clock, n_threads=n_threads,
                             time_budget=time_budget, eval_every=eval_every,
                             early_stopping=early_stopping, render_size=render_size,
                             callback=callback, verbose=verbose, progress=progress)
    status, message = training.run()
    n_steps = len(training.history.steps)
    images_out = p_final = None
    if test is not None:
        images_out, p_final, _ = training.evaluate()
    return NerfFitResult(
        status=status, message=message, history=training.history, n_params=field.n_params,
        seconds=clock.elapsed(), cpu_seconds=clock.cpu_elapsed(), n_iterations=n_steps,
        n_evaluations=n_steps, field=field, config=cfg, occupancy=training.hull,
        samples_per_ray=training.spr_sum / max(n_steps, 1), psnr=p_final, images=images_out,
        wall_seconds=time.perf_counter() - t_wall, method=method, recipe=recipe, init=init)


def _check_step_memory(cfg: NerfConfig, n_views: int, n_threads: int) -> None:
    """Memory guard (issue 18): one training step's samples and network activations
    (measured ~13 B per hidden unit and sample)."""
    from geofit._memory import check_allocation

    from ._nerf_train import _CHUNK_SAMPLES

    batch = min(cfg.batch_size, n_views)
    per, step = 13 * np.dtype(cfg.dtype).itemsize * cfg.n_hidden_neurons, batch * \
        cfg.n_rays_per_image * cfg.n_pts_per_ray  # B per sample, samples per step
    check_allocation(per * min(step, n_threads * max(_CHUNK_SAMPLES, cfg.n_pts_per_ray))
                     + 64 * step, "batch_size, n_rays_per_image and n_pts_per_ray",
                     "one training step's samples and network activations")


def _config(recipe: str, config, overrides) -> NerfConfig:
    """The recipe's configuration (or ``config``) with ``overrides``, validated."""
    if config is None:
        config = NerfConfig.scene() if recipe == "default" else NerfConfig.tutorial()
    elif not isinstance(config, NerfConfig):
        raise TypeError(f"config: expected a NerfConfig, got {type(config)!r}")
    try:
        return replace(config, **overrides).validate()
    except TypeError as exc:
        raise ValueError(f"overrides: {exc}") from None


def _initial_field(init, cfg: NerfConfig, rng) -> tuple[NeuralRadianceField, NerfConfig]:
    """A new network of the configuration, or a copy of ``init`` (whose architecture then
    replaces the configuration's)."""
    if init is None:
        return cfg.network(seed=rng), cfg
    if not isinstance(init, NeuralRadianceField):
        raise TypeError(f"init: expected a NeuralRadianceField, got {type(init)!r}")
    field = init.astype(cfg.dtype)
    c = field.config
    cfg = replace(cfg, **{k: c[k] for k in (
        "n_harmonic_functions", "omega0", "append_input", "n_hidden_neurons",
        "n_hidden_layers", "n_harmonic_functions_dir", "omega0_dir", "n_hidden_color",
        "activation", "beta")})
    return field, cfg
