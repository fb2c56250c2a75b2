"""Fit a neural radiance field to posed images (PyTorch3D's sixth tutorial), on the CPU.

The tutorial (``fit_simple_neural_radiance_field``) fits :class:`NeuralRadianceField` (60
frequencies, two hidden layers of 256 with Softplus(beta=10), 317,188 parameters) to 40 views of
the cow: per step 6 random views, 750 Monte Carlo rays per view with 128 samples each over view
depths [0.1, 3.0], Huber losses (scale 0.1) on the colours and the silhouettes (targets sampled
bilinearly at the rays' xy), Adam with lr 1e-3 for 3000 steps and a new Adam at lr 1e-4 from 75 %.
:func:`fit_nerf` with ``preset="tutorial"`` runs exactly that recipe, with the gradients of
:mod:`geofit.render.volume` (pixels -> raymarcher vjp -> density and colour heads -> trunk).

geofit's scene-sized recipe (``preset="scene"``) fits the same kind of field but models no more
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

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from .._threads import get_num_threads, parallel_map
from .._validate import as_array, as_rng, as_unit_images, check_choice, check_positive
from ..cameras import CamerasBase
from ..loss.robust import huber
from ..metrics import psnr
from ..nn.optim import Adam, exponential_decay, step_decay
from ..render.volume import (
    EmissionAbsorptionRaymarcher,
    ImplicitRenderer,
    MonteCarloRaysampler,
    NDCMultinomialRaysampler,
    NeuralRadianceField,
    OccupancyGrid,
    RayBundle,
)
from .history import Clock, FitHistory, FitResult

__all__ = [
    "NERF_PRESETS",
    "NerfConfig",
    "NerfFitResult",
    "fit_nerf",
    "render_nerf",
    "sample_images_at_xys",
]

#: Presets of :func:`fit_nerf`.
NERF_PRESETS = ("scene", "tutorial")

#: Candidate samples per chunk of a training step (bounds the memory of the caches).
_CHUNK_SAMPLES = 1 << 17


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------


@dataclass
class NerfConfig:
    """Every setting of :func:`fit_nerf`; :meth:`tutorial` and :meth:`scene` are the presets.

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
    if held_out is None:
        return None
    if hasattr(held_out, "images") and hasattr(held_out, "cameras"):
        return _Data(held_out.images, held_out.silhouettes, held_out.cameras, "held_out.")
    try:
        images, silhouettes, cameras = held_out
    except (TypeError, ValueError):
        raise ValueError("held_out: expected (images, silhouettes, cameras) or an object with "
                         "those attributes") from None
    return _Data(images, silhouettes, cameras, "held_out.")


def _silhouette_weights(silhouettes: np.ndarray, margin: int) -> np.ndarray:
    """(N, H, W) 0/1 weights of the silhouette loss: 0 in a band ``margin`` pixels wide just
    inside each silhouette's edge, 1 elsewhere."""
    from scipy.ndimage import binary_erosion

    inside = silhouettes > 0.5
    core = np.stack([binary_erosion(m, structure=np.ones((3, 3), bool), iterations=margin,
                                    border_value=1) for m in inside])  # views
    return (~inside | core).astype(np.float64)


class _DensityGrid:
    """The coarse density grid: the network's opacity at a random point of each hull voxel."""

    #: Per update, a voxel's opacity estimate keeps this fraction of its previous value (a
    #: voxel is dropped only after several updates find it empty).
    decay = 0.7

    def __init__(self, hull: OccupancyGrid, cfg: NerfConfig):
        self.hull = hull
        self.cfg = cfg
        self.cells = np.flatnonzero(hull.occupied.reshape(-1))
        self.opacity = np.ones(hull.occupied.size, dtype=np.float32)  # unknown: occupied
        self.opacity[~hull.occupied.reshape(-1)] = 0.0

    def update(self, field: NeuralRadianceField, rng: np.random.Generator, n_threads: int
               ) -> OccupancyGrid:
        hull = self.hull
        W, H, _ = hull.shape_xyz
        cz, rem = np.divmod(self.cells, H * W)
        cy, cx = np.divmod(rem, W)
        ijk = np.stack([cx, cy, cz], axis=1) + rng.random((self.cells.size, 3))
        pts = hull.bounds[0] + ijk * hull.voxel_size
        dirs = np.array([[0.0, 0.0, 1.0]])
        chunks = [pts[s:s + 65536] for s in range(0, len(pts), 65536)]

        def work(p):
            idx = np.zeros(len(p), dtype=np.int64)
            return field._forward(p, dirs, idx, None, False)[0][:, 0]

        new = np.concatenate(parallel_map(work, chunks, n_threads)) if len(pts) else \
            np.zeros(0, np.float32)
        old = self.opacity[self.cells]
        self.opacity[self.cells] = np.maximum(new, self.decay * np.minimum(old, 1.0))
        grid = self.opacity.reshape(hull.occupied.shape)
        occ = OccupancyGrid(grid > self.cfg.density_threshold, hull.bounds).dilate(1)
        return OccupancyGrid(occ.occupied & hull.occupied, hull.bounds, grid)


def fit_nerf(images, silhouettes, cameras: CamerasBase, *, preset: str = "scene",
             config: NerfConfig | None = None, held_out=None, time_budget: float | None = None,
             eval_every: float | None = None, early_stopping: int | None = None,
             render_size: int | None = None, init: NeuralRadianceField | None = None, seed=0,
             callback: Callable[[dict], bool | None] | None = None, verbose: bool = False,
             **overrides) -> NerfFitResult:
    """Fit a neural radiance field to posed RGB images and silhouettes.

    Parameters
    ----------
    images : (N, H, W, 3) float64
        Training images in [0, 1] (black background, as the tutorial's renders).
    silhouettes : (N, H, W) float64
        Training silhouettes in [0, 1].
    cameras : CamerasBase
        The ``N`` cameras.
    preset : {"scene", "tutorial"}
        Base settings (:meth:`NerfConfig.scene` or :meth:`NerfConfig.tutorial`).
    config : NerfConfig, optional
        Settings to use instead of the preset.
    held_out : (images, silhouettes, cameras) or object with those attributes, optional
        Views not trained on: rendered in full at checkpoints (PSNR and Huber loss) and at the
        end.
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
    **overrides
        Fields of :class:`NerfConfig` replacing the preset's.

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
    check_choice(preset, "preset", NERF_PRESETS)
    if config is None:
        config = NerfConfig.scene() if preset == "scene" else NerfConfig.tutorial()
    elif not isinstance(config, NerfConfig):
        raise TypeError(f"config: expected a NerfConfig, got {type(config)!r}")
    try:
        cfg = replace(config, **overrides).validate()
    except TypeError as exc:
        raise ValueError(f"overrides: {exc}") from None
    data = _Data(images, silhouettes, cameras, "")
    test = _held_out(held_out)
    if time_budget is not None:
        time_budget = check_positive(time_budget, "time_budget")
    if early_stopping is not None:
        if test is None:
            raise ValueError("early_stopping: needs held_out views")
        if not isinstance(early_stopping, (int, np.integer)) or early_stopping < 1:
            raise ValueError(f"early_stopping: expected an integer >= 1, got {early_stopping!r}")
    rng = as_rng(seed)
    clock = Clock()  # the set-up (hull, rays) is part of the method's time
    n_threads = get_num_threads() if cfg.n_threads is None else int(cfg.n_threads)
    if init is None:
        field = cfg.network(seed=rng)
    elif isinstance(init, NeuralRadianceField):
        field = init.astype(cfg.dtype)
        c = field.config
        cfg = replace(cfg, **{k: c[k] for k in (
            "n_harmonic_functions", "omega0", "append_input", "n_hidden_neurons",
            "n_hidden_layers", "n_harmonic_functions_dir", "omega0_dir", "n_hidden_color",
            "activation", "beta")})
    else:
        raise TypeError(f"init: expected a NeuralRadianceField, got {type(init)!r}")
    batch = min(cfg.batch_size, data.N)
    from geofit._memory import check_allocation  # memory guard (issue 18), measured ~13
    per, step = 13 * np.dtype(cfg.dtype).itemsize * cfg.n_hidden_neurons, batch * \
        cfg.n_rays_per_image * cfg.n_pts_per_ray  # B per sample, samples per step
    check_allocation(per * min(step, n_threads * max(_CHUNK_SAMPLES, cfg.n_pts_per_ray))
                     + 64 * step, "batch_size, n_rays_per_image and n_pts_per_ray",
                     "one training step's samples and network activations")

    # ---- occupancy and rays ----------------------------------------------------------------
    hull = None
    if cfg.occupancy != "none":
        hull = OccupancyGrid.from_silhouettes(
            data.silhouettes, data.cameras, resolution=cfg.hull_resolution, bounds=cfg.bounds,
            dilate_pixels=cfg.hull_dilate_pixels).dilate(1)
    raymarcher = EmissionAbsorptionRaymarcher()
    grid_sampler = NDCMultinomialRaysampler(
        image_width=data.W, image_height=data.H, n_pts_per_ray=cfg.n_pts_per_ray,
        min_depth=cfg.min_depth, max_depth=cfg.max_depth, stratified_sampling=cfg.stratified)
    if cfg.ray_sampling == "montecarlo":
        sampler = MonteCarloRaysampler(-1.0, 1.0, -1.0, 1.0, cfg.n_rays_per_image,
                                       cfg.n_pts_per_ray, cfg.min_depth, cfg.max_depth,
                                       stratified_sampling=cfg.stratified)
    else:
        sampler = grid_sampler
    density = _DensityGrid(hull, cfg) if cfg.occupancy == "density" else None
    renderer = ImplicitRenderer(
        sampler, raymarcher, occupancy=hull,
        min_transmittance=cfg.min_transmittance if density is not None else 0.0,
        occlusion_margin=cfg.occlusion_margin)
    pixel_rays = hit_pixels = None
    if cfg.ray_sampling == "pixels":
        full = grid_sampler(data.cameras, stratified_sampling=False)
        pixel_rays = RayBundle(full.origins.reshape(data.N, -1, 3),
                               full.directions.reshape(data.N, -1, 3), None,
                               full.xys.reshape(data.N, -1, 2))
        # every ray that meets the hull passes through the view's dilated silhouette (the hull
        # was carved from it, then grown by one voxel: allow two more pixels for that)
        from scipy.ndimage import binary_dilation

        grow = cfg.hull_dilate_pixels + 2
        hit_pixels = [np.flatnonzero(binary_dilation(data.silhouettes[i] > 0.5,
                                                     structure=np.ones((3, 3), bool),
                                                     iterations=grow))
                      for i in range(data.N)]  # views
        if any(h.size == 0 for h in hit_pixels):
            empty = [i for i, h in enumerate(hit_pixels) if h.size == 0]
            raise ValueError(f"silhouettes: no ray of view(s) {empty} meets the visual hull; "
                             "check the silhouettes and cameras")
    base_lengths = np.linspace(cfg.min_depth, cfg.max_depth, cfg.n_pts_per_ray)
    img_flat = data.images.reshape(data.N, -1, 3)
    sil_flat = data.silhouettes.reshape(data.N, -1)
    sil_weight = None
    if cfg.silhouette_margin > 0 and cfg.ray_sampling == "pixels":
        sil_weight = _silhouette_weights(data.silhouettes, cfg.silhouette_margin).reshape(
            data.N, -1)

    # ---- schedule ---------------------------------------------------------------------------
    if cfg.lr_schedule == "step":
        schedule = step_decay(cfg.lr, cfg.n_iter, at=cfg.lr_decay_at, factor=cfg.lr_decay_factor,
                              reset=True)
    else:
        schedule = exponential_decay(cfg.lr, cfg.lr * cfg.lr_decay_factor, 10 ** 6)

    def lr_at(step: int, seconds: float) -> tuple[float, bool]:
        if cfg.lr_schedule == "step":
            return schedule(step)
        frac = step / cfg.n_iter
        if time_budget is not None:
            frac = max(frac, seconds / time_budget)
        return schedule(int(min(frac, 1.0) * 10 ** 6))

    opt = Adam(field.params, lr=cfg.lr)

    # ---- one step ---------------------------------------------------------------------------
    def draw_batch():
        views = rng.choice(data.N, size=batch, replace=False)
        if cfg.ray_sampling == "montecarlo":
            bundle = sampler(data.cameras[views], seed=rng)
            xys = bundle.xys
            tgt_rgb = sample_images_at_xys(data.images[views], xys)
            tgt_sil = sample_images_at_xys(data.silhouettes[views][..., None], xys)[..., 0]
            flat = RayBundle(*(np.asarray(a).reshape(-1, a.shape[-1]) for a in bundle))
            return flat, tgt_rgb.reshape(-1, 3), tgt_sil.reshape(-1), None
        pix = np.stack([rng.choice(hit_pixels[v], size=cfg.n_rays_per_image,
                                   replace=hit_pixels[v].size < cfg.n_rays_per_image)
                        for v in views])  # views
        o = pixel_rays.origins[views[:, None], pix].reshape(-1, 3)
        d = pixel_rays.directions[views[:, None], pix].reshape(-1, 3)
        xys = pixel_rays.xys[views[:, None], pix].reshape(-1, 2)
        lengths = np.broadcast_to(base_lengths, (o.shape[0], cfg.n_pts_per_ray))
        if cfg.stratified:
            step = (cfg.max_depth - cfg.min_depth) / max(cfg.n_pts_per_ray - 1, 1)
            lengths = lengths + (rng.random((o.shape[0], 1)) - 0.5) * step
        flat = RayBundle(o, d, np.ascontiguousarray(lengths), xys)
        w = None if sil_weight is None else sil_weight[views[:, None], pix].reshape(-1)
        return (flat, img_flat[views[:, None], pix].reshape(-1, 3),
                sil_flat[views[:, None], pix].reshape(-1), w)

    # the opacity regulariser starts with the density grid (after the warm-up), once the
    # network has found the object: from the start it would empty the hull before that
    reg_on = [cfg.opacity_regularization > 0 and (density is None
                                                  or cfg.density_grid_warmup == 0)]

    def loss_and_grads(flat: RayBundle, tgt_rgb, tgt_sil, sil_w):
        R = flat.origins.shape[0]
        # chunks of at most _CHUNK_SAMPLES candidate samples (bounded memory), a multiple of
        # the thread count; every chunk's gradients are summed
        n_parts = max(n_threads, -(-R * cfg.n_pts_per_ray // _CHUNK_SAMPLES))
        n_parts = -(-n_parts // n_threads) * n_threads
        parts = [slice(i * R // n_parts, (i + 1) * R // n_parts) for i in range(n_parts)]

        def work(sl):
            sub = RayBundle(*(a[sl] for a in flat))
            img, _, cache = renderer.render(None, field, ray_bundle=sub)
            lc, gc = huber(img[:, :3], tgt_rgb[sl], cfg.huber_scale)
            ls, gs = huber(img[:, 3], tgt_sil[sl], cfg.huber_scale)
            if sil_w is not None:
                ls, gs = ls * sil_w[sl], gs * sil_w[sl]
            G = np.empty_like(img)
            G[:, :3] = gc / (3 * R)
            G[:, 3] = gs / R
            lo, gd = 0.0, None
            if reg_on[0] and cache.ray_index.size:
                a = cache.sample_densities()
                w = cfg.opacity_regularization / R
                lo = w * float(np.sum(a * (1.0 - a)))
                gd = w * (1.0 - 2.0 * a)
            grads = renderer.backward(field, cache, G, gd)
            k = cache.ray_index.size
            return lc.sum() / (3 * R), ls.sum() / R, lo, grads, k

        outs = parallel_map(work, [p for p in parts if p.stop > p.start], n_threads)
        terms = {"color": sum(o[0] for o in outs), "silhouette": sum(o[1] for o in outs)}
        if cfg.opacity_regularization > 0:
            terms["opacity"] = sum(o[2] for o in outs)
        grads = {k: sum(o[3][k] for o in outs) for k in outs[0][3]}
        return terms, grads, sum(o[4] for o in outs) / R

    # ---- held-out evaluation -----------------------------------------------------------------
    size = None
    test_sil_weight = None
    if test is not None and sil_weight is not None:
        test_sil_weight = _silhouette_weights(test.silhouettes, cfg.silhouette_margin)
    if test is not None:
        size = (test.H, test.W) if render_size is None else (int(render_size),) * 2

    def evaluate():
        imgs = render_nerf(field, test.cameras, size, n_pts_per_ray=cfg.n_pts_per_ray,
                           min_depth=cfg.min_depth, max_depth=cfg.max_depth, occupancy=hull,
                           chunk_rays=cfg.chunk_rays, n_threads=n_threads)
        if size != (test.H, test.W):
            return imgs, None, None
        rgb = np.clip(imgs[..., :3], 0.0, 1.0)
        lc = huber(imgs[..., :3], test.images, cfg.huber_scale)[0].mean()
        ls = huber(imgs[..., 3], test.silhouettes, cfg.huber_scale)[0]
        if test_sil_weight is not None:
            ls = ls * test_sil_weight
        return imgs, psnr(rgb, test.images), float(lc + ls.mean())

    # ---- loop -------------------------------------------------------------------------------
    history = FitHistory()
    n_params = field.n_params
    if eval_every is None:
        every = (time_budget / 20.0) if time_budget is not None else max(cfg.n_iter // 20, 1)
    else:
        every = check_positive(eval_every, "eval_every")
    next_eval = every
    status, message = "max_iter", f"completed {cfg.n_iter} steps"
    best = {"loss": math.inf, "params": None, "step": 0, "since": 0}
    last_good = {k: v.copy() for k, v in field.params.items()}
    spr_sum = 0.0
    step = 0
    stage = 0
    if density is not None and cfg.density_grid_warmup == 0:
        renderer.occupancy = density.update(field, rng, n_threads)
    initial = None
    if test is not None:
        with clock.paused():  # the untrained network's held-out loss: the reference for progress
            initial = evaluate()[2]

    def checkpoint(step: int, loss: float) -> bool:
        """Record metrics (clock paused); True to stop."""
        with clock.paused():
            info = {"step": step, "seconds": clock.elapsed(), "loss": loss}
            metrics = None
            if test is not None:
                _, p, hl = evaluate()
                metrics = {"psnr": p, "held_out_loss": hl}
                info.update(metrics)
                if hl < best["loss"]:
                    best.update(loss=hl, params={k: v.copy() for k, v in field.params.items()},
                                step=step, since=0)
                else:
                    best["since"] += 1
            history.checkpoint(step, info["seconds"], metrics or {"loss": loss})
            if verbose:
                extra = "" if test is None else (f" held-out PSNR {info['psnr']:.2f} dB, "
                                                 f"loss {info['held_out_loss']:.4f}")
                print(f"fit_nerf: step {step}, {info['seconds']:.1f} s, loss {loss:.4f}, "
                      f"samples/ray {spr_sum / max(step, 1):.1f}{extra}", flush=True)
            stop = bool(callback(info)) if callback is not None else False
        return stop

    for step in range(1, cfg.n_iter + 1):  # Adam steps
        lr, reset = lr_at(step - 1, clock.elapsed())
        opt.set_lr(lr, reset=reset)
        if density is not None and step > cfg.density_grid_warmup and \
                (step - cfg.density_grid_warmup - 1) % cfg.density_grid_every == 0:
            renderer.occupancy = density.update(field, rng, n_threads)
            reg_on[0] = cfg.opacity_regularization > 0
            if stage == 0:
                stage = 1
                history.note(step, clock.elapsed(), "density grid: skipping empty and occluded "
                             "samples", occupied=renderer.occupancy.fraction_occupied)
        flat, tgt_rgb, tgt_sil, sil_w = draw_batch()
        terms, grads, spr = loss_and_grads(flat, tgt_rgb, tgt_sil, sil_w)
        loss = sum(terms.values())
        finite = math.isfinite(loss) and all(np.all(np.isfinite(g)) for g in grads.values())
        if not finite:
            field.set_params(last_good)
            status = "nonfinite"
            message = (f"the loss or its gradient became NaN or inf at step {step}; returning "
                       "the last finite parameters")
            history.record(step, clock.elapsed(), loss if math.isfinite(loss) else math.nan,
                           terms, n_params=n_params, stage=stage)
            break
        for k, v in field.params.items():  # parameter arrays
            last_good[k][...] = v
        opt.step(grads)
        if not all(np.all(np.isfinite(v)) for v in field.params.values()):
            field.set_params(last_good)
            status = "nonfinite"
            message = (f"the parameters became NaN or inf at step {step} (learning rate "
                       f"{lr:g} too large?); returning the last finite parameters")
            break
        spr_sum += spr
        seconds = clock.elapsed()
        history.record(step, seconds, loss, terms, n_params=n_params, stage=stage)
        out_of_time = time_budget is not None and seconds >= time_budget
        due = (seconds >= next_eval) if time_budget is not None else (step >= next_eval)
        if due or out_of_time or step == cfg.n_iter:
            next_eval += every
            if checkpoint(step, loss):
                status, message = "callback", f"the callback stopped the fit at step {step}"
                break
            if early_stopping is not None and best["since"] >= early_stopping:
                status = "converged"
                message = (f"the held-out loss has not improved for {early_stopping} "
                           f"checkpoints; returning the best one (step {best['step']})")
                break
        if out_of_time:
            status, message = "time_budget", (f"stopped after {seconds:.1f} s (time budget "
                                              f"{time_budget:g} s) at step {step}")
            break
    n_steps = len(history.steps)
    if status in ("max_iter", "time_budget"):
        # no progress (a learning rate far too large kills the network rather than making it
        # NaN): the held-out loss no better than the untrained network's, or the training
        # loss of the last tenth of the steps above 80 % of that of the first ten steps
        L = np.asarray(history.loss)
        tail = L[-max(n_steps // 10, 1):].mean() if n_steps else math.nan
        head = L[:10].mean() if n_steps else math.nan
        last = history.checkpoints[-1].get("held_out_loss") if history.checkpoints else None
        if initial is not None and last is not None and last >= initial:
            status = "diverged"
            message = (f"no progress: the held-out loss went from {initial:.4g} (initial "
                       f"network) to {last:.4g} after {n_steps} steps; learning rate "
                       f"{cfg.lr:g} too large?")
        elif n_steps >= 50 and tail > 0.8 * head:
            status = "diverged"
            message = (f"no progress: the training loss went from {head:.4g} (first 10 steps) "
                       f"to {tail:.4g} (last {max(n_steps // 10, 1)} steps); learning rate "
                       f"{cfg.lr:g} too large?")
        if status == "diverged" and best["params"] is not None and last is not None and \
                best["loss"] < last:
            field.set_params(best["params"])
            message += f"; returning the best checkpoint (step {best['step']})"
    if early_stopping is not None and best["params"] is not None:
        field.set_params(best["params"])
    images_out = p_final = None
    if test is not None:
        images_out, p_final, _ = evaluate()
    return NerfFitResult(
        status=status, message=message, history=history, n_params=n_params,
        seconds=clock.elapsed(), n_iterations=n_steps, n_evaluations=n_steps, field=field,
        config=cfg, occupancy=hull, samples_per_ray=spr_sum / max(n_steps, 1), psnr=p_final,
        images=images_out, wall_seconds=time.perf_counter() - t_wall)
