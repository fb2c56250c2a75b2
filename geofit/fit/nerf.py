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
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from .._memory import check_allocation, check_mlp_size
from .._threads import get_num_threads
from .._validate import as_array, as_rng, as_unit_images, check_choice, check_positive
from ..cameras import CamerasBase
from ..loss.robust import huber
from ..render.volume import NeuralRadianceField, OccupancyGrid
from ._nerf_render import render_nerf, sample_images_at_xys
from ._nerf_train import _CHUNK_SAMPLES, _Solver
from ._options import as_dataset, check_int, recipe_name
from .history import Clock, FitResult
from .solvers import StepInfo

__all__ = [
    "RECIPES",
    "NerfConfig",
    "NerfFitResult",
    "fit_nerf",
    "huber",
    "render_nerf",
    "sample_images_at_xys",
]


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NerfConfig:
    """Every setting of :func:`fit_nerf` (its options object); :meth:`tutorial` and
    :meth:`scene` are the recipes (:data:`RECIPES`).

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

    Start and stop: ``init`` (a :class:`~geofit.render.NeuralRadianceField` to start from: a
    copy of it is trained, and its architecture replaces the configuration's; the density grid
    starts from the visual hull as usual); ``early_stopping`` (stop with status
    ``"converged"`` when the held-out loss has not improved for this many checkpoints, and
    return the best checkpoint's field); ``render_size`` (size of the final held-out renders;
    None: the held-out images' size).
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
    init: Any = None
    early_stopping: int | None = None
    render_size: int | None = None

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
        if self.early_stopping is not None and (
                not isinstance(self.early_stopping, (int, np.integer))
                or isinstance(self.early_stopping, bool) or self.early_stopping < 1):
            raise ValueError(f"early_stopping: expected an integer >= 1, got "
                             f"{self.early_stopping!r}")
        if self.ray_sampling == "pixels" and self.occupancy == "none":
            raise ValueError("ray_sampling: 'pixels' draws rays among the pixels that meet the "
                             "occupancy grid; use occupancy='hull' or 'density'")
        return self


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------


#: Recipes of :func:`fit_nerf` (:class:`NerfConfig` presets): geofit's scene-sized field, or
#: the tutorial's.
RECIPES: dict[str, NerfConfig] = {"default": NerfConfig.scene(),
                                  "tutorial": NerfConfig.tutorial()}


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
    """

    field: NeuralRadianceField
    config: NerfConfig
    occupancy: OccupancyGrid | None = None
    samples_per_ray: float = 0.0
    psnr: float | None = None
    images: np.ndarray | None = None

    def render(self, cameras: CamerasBase, image_size) -> np.ndarray:
        """(N, H, W, 4) float64 full-image renders (RGB, opacity) of :attr:`field` from
        ``cameras`` with the fit's sampling and occupancy (:func:`render_nerf`): e.g. the
        held-out views when the time budget left their final render out (``images`` None)."""
        c = self.config
        return render_nerf(self.field, cameras, image_size, n_pts_per_ray=c.n_pts_per_ray,
                           min_depth=c.min_depth, max_depth=c.max_depth,
                           occupancy=self.occupancy, chunk_rays=c.chunk_rays,
                           n_threads=c.n_threads)

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d.update({"samples_per_ray": self.samples_per_ray, "psnr": self.psnr, "config": {f.name: getattr(self.config, f.name)
                             for f in fields(self.config) if f.name != "init"}})
        return d


# --------------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------------


class _Dataset:
    """Training or held-out views, validated once at the door."""

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


def _as_dataset(dataset) -> _Dataset:
    """The training views (a MultiViewDataset with RGB images), checked once."""
    return _Dataset(dataset.images, dataset.silhouettes, dataset.cameras, "")


def _held_out(evaluator, dataset) -> _Dataset | None:
    """The held-out views of ``evaluator``: "default" (the dataset's), None, or views."""
    if isinstance(evaluator, str):
        check_choice(evaluator, "evaluator", ("default",))
        evaluator = dataset.held_out
    if evaluator is None:
        return None
    if hasattr(evaluator, "images") and hasattr(evaluator, "cameras"):
        return _Dataset(evaluator.images, evaluator.silhouettes, evaluator.cameras,
                        "evaluator.")
    try:
        images, silhouettes, cameras = evaluator
    except (TypeError, ValueError):
        raise TypeError("evaluator: expected 'default', None, a MultiViewDataset or (images, "
                        "silhouettes, cameras)") from None
    return _Dataset(images, silhouettes, cameras, "evaluator.")


def fit_nerf(dataset, *, recipe: str = "default", options: NerfConfig | None = None,
             time_budget: float | None = None, seed=0, evaluator="default",
             eval_every: int | None = None,
             callback: Callable[[StepInfo], bool | None] | None = None,
             progress: bool = True) -> NerfFitResult:
    """Fit a neural radiance field to posed RGB images and silhouettes.

    Parameters
    ----------
    dataset : MultiViewDataset
        Training images in [0, 1] (black background, as the tutorial's renders), silhouettes
        in [0, 1] and the ``N`` cameras.
    recipe : {"default", "tutorial"}
        Named settings (:data:`RECIPES`): geofit's scene-sized recipe (:meth:`NerfConfig.scene`)
        or the tutorial's (:meth:`NerfConfig.tutorial`).
    options : NerfConfig, optional
        The settings, used instead of the recipe's (build them from a recipe with
        ``NerfConfig.scene(**changes)`` or ``NerfConfig.tutorial(**changes)``).
    time_budget : float, optional
        Wall-clock seconds for the whole fit, set-up and held-out renders included (not the
        time spent in the callback you pass): the training stops (status ``"time_budget"``)
        early enough for the final held-out render, timed on the longest render so far, to end
        within the budget, and a checkpoint is skipped when its render would not leave that.
    seed : int or numpy.random.Generator
        Initialisation, view and ray choices.
    evaluator : "default", MultiViewDataset, (images, silhouettes, cameras) or None
        Held-out views, rendered in full at checkpoints (PSNR and Huber loss) and at the end;
        ``"default"``: ``dataset.held_out``; None: none.
    eval_every : int, optional
        Steps between checkpoints (default: 1/20 of ``n_iter``; with a time budget, every
        1/20 of the budget).
    callback : callable, optional
        ``callback(StepInfo) -> bool | None`` at each checkpoint (``info.x`` the network's
        flat parameters, ``info.value`` the training loss, ``info.metrics`` the held-out PSNR
        and loss); True stops the fit (status ``"callback"``).
    progress : bool
        Show a tqdm progress bar (on stderr; steps, or seconds of the time budget).

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
    dataset = as_dataset(dataset, fit="fit_nerf", silhouettes="full")
    data = _as_dataset(dataset)
    test = _held_out(evaluator, dataset)
    recipe = recipe_name(recipe, RECIPES, fit="fit_nerf")
    cfg = _config(recipe, options)
    if time_budget is not None:
        time_budget = check_positive(time_budget, "time_budget")
    if eval_every is not None:
        eval_every = check_int(eval_every, "eval_every")
    if cfg.early_stopping is not None and test is None:
        raise ValueError("options.early_stopping: needs held-out views (evaluator)")
    rng = as_rng(seed)
    clock = Clock(time_budget)  # the set-up (hull, rays) is part of the method's time
    n_threads = get_num_threads() if cfg.n_threads is None else int(cfg.n_threads)
    field, cfg = _initial_field(cfg, rng)
    _check_step_memory(cfg, data.N, n_threads)
    solver = _Solver(cfg, data, test, field, rng=rng, clock=clock, n_threads=n_threads,
                     time_budget=time_budget, eval_every=eval_every, callback=callback,
                     progress=progress)
    status, message = solver.run()
    n_steps = len(solver.history.steps)
    images_out = p_final = None
    if test is not None:
        images_out, p_final, _ = solver.final_render()
    if solver.skipped:
        message += f"; left out to keep the time budget: {', '.join(solver.skipped)}"
    return NerfFitResult(
        status=status, message=message, history=solver.history, n_params=field.n_params,
        seconds=clock.elapsed(), cpu_seconds=clock.cpu_elapsed(), n_iterations=n_steps,
        total_cpu_seconds=clock.cpu_total(),
        n_evaluations=n_steps, field=field, config=cfg, occupancy=solver.hull,
        samples_per_ray=solver.spr_sum / max(n_steps, 1), psnr=p_final, images=images_out,
        wall_seconds=time.perf_counter() - t_wall, method="adam", recipe=recipe,
        init=cfg.init)


def _check_step_memory(cfg: NerfConfig, n_views: int, n_threads: int) -> None:
    """Memory guard (issue 18): one training step's samples and network activations
    (measured ~13 B per hidden unit and sample)."""
    batch = min(cfg.batch_size, n_views)
    per, step = 13 * np.dtype(cfg.dtype).itemsize * cfg.n_hidden_neurons, batch * \
        cfg.n_rays_per_image * cfg.n_pts_per_ray  # B per sample, samples per step
    check_allocation(per * min(step, n_threads * max(_CHUNK_SAMPLES, cfg.n_pts_per_ray))
                     + 64 * step, "batch_size, n_rays_per_image and n_pts_per_ray",
                     "one training step's samples and network activations")


def _config(recipe: str, options) -> NerfConfig:
    """The recipe's configuration, or ``options``, validated."""
    if options is None:
        options = NerfConfig.scene() if recipe == "default" else NerfConfig.tutorial()
    elif not isinstance(options, NerfConfig):
        raise TypeError(f"options: expected a NerfConfig, got {type(options)!r}")
    return options.validate()


def _initial_field(cfg: NerfConfig, rng) -> tuple[NeuralRadianceField, NerfConfig]:
    """A new network of the configuration, or a copy of ``cfg.init`` (whose architecture then
    replaces the configuration's)."""
    init = cfg.init
    if init is None:
        return cfg.network(seed=rng), cfg
    if not isinstance(init, NeuralRadianceField):
        raise TypeError(f"options.init: expected a NeuralRadianceField, got {type(init)!r}")
    field = init.astype(cfg.dtype)
    c = field.config
    cfg = replace(cfg, **{k: c[k] for k in (
        "n_harmonic_functions", "omega0", "append_input", "n_hidden_neurons",
        "n_hidden_layers", "n_harmonic_functions_dir", "omega0_dir", "n_hidden_color",
        "activation", "beta")})
    return field, cfg
