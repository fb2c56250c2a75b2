"""Fit a mesh and its vertex colours to multi-view images (PyTorch3D's fit_textured_mesh tutorial).

The tutorial renders the cow from 20 views (RGB and soft silhouettes, 128 x 128), deforms an
``ico_sphere(4)`` to match the silhouettes (SGD, two random views per step, edge / normal /
Laplacian regularisers), then fits vertex positions and per-vertex colours to the RGB images.
Here every gradient is analytic (:mod:`geofit.render.soft`), and the chain rule is composed in
plain sight in :class:`_Objective`.

* The data: a :class:`geofit.datasets.MultiViewDataset` (``geofit.datasets.tutorial_views(4)``
  renders the tutorial's, with held-out views for evaluation).
* :func:`fit_mesh_to_views` -- a silhouette stage, then a textured stage. The default
  (recipe ``"default"``) is geofit's best for any shape: it starts from the **visual hull** of
  the silhouettes (:mod:`geofit.fit._views_init`: carved at the soft silhouettes' 0.5 level,
  marching cubes, quadric decimation; the hull's genus and parts),
  then alternates L-BFGS on the soft silhouettes of all views (large steps, lambda 10; 64 then
  128 px) with **remeshing** (:func:`geofit.ops.remesh`) to edges of ``edge_px`` = 3 pixels
  of the level's images, and ends with least-squares colours. Every length is a number of
  pixels times the pixel's world size at the object (:func:`~geofit.fit._views_init.
  pixel_footprint`), so nothing depends on the object's scale. The hull is only a start:
  with 50 faces blended, a soft silhouette exceeds 0.5 up to about a pixel outside the
  outline (on the cow's 20 views 5472 such pixels against 65798 inside), so the 0.5 hull is
  inflated (held-out IoU 0.889, F@0.01 0.001 on the cow, measured); the fit matches the
  targets with the same soft model, which the true mesh fits exactly (its soft render equals
  the targets to 1e-18). ``init="sphere"`` keeps the tutorial's ico-sphere.
  Silhouette methods (:data:`SILHOUETTE_METHODS`):

  - ``"sgd"`` (recipe ``"tutorial"``): the tutorial's recipe (SGD lr 1, momentum 0.9, two
    random views per step, soft silhouettes, weights silhouette 1, edge 1, normal 0.01,
    Laplacian 1);
  - ``"lbfgs"`` / ``"lbfgs-nlopt"``: the same objective over *all* views (deterministic),
    optionally with the large-steps parameterisation and coarse-to-fine levels (image size and
    mesh level rising together);
  - ``"adam"`` with ``silhouette_loss="contour"`` (recipe ``"contour"``): geometry-first: the
    hard silhouette's loss differentiated by edge sampling along the mesh's projected contour
    (:mod:`geofit.render.soft.contour`), Adam in the large-steps parameterisation,
    coarse-to-fine.

  Textured methods (:data:`TEXTURED_METHODS`): ``"sgd"`` (the tutorial's: SGD on offsets and
  colours, two
  views per step, weights RGB 1, silhouette 1, edge 1, normal 0.01, Laplacian 1), ``"lstsq"``
  (colours by one sparse least-squares solve on the hard render of the fitted geometry: for
  fixed geometry the image is affine in the colours), ``"lbfgs"`` (``lstsq`` colours, then joint
  L-BFGS on positions and colours over all views with the soft Phong renderer). On the cow the
  joint refinement lowers the held-out PSNR (24.3 -> 23.3 dB in 120 s, measured): the soft
  Phong image (blur, 50 faces blended) is not the hard image the targets are, and the
  least-squares colours already fit the hard image optimally for the geometry.
* :class:`ViewsEvaluator` -- held-out metrics (:func:`geofit.metrics.silhouette_iou`,
  :func:`geofit.metrics.psnr`; chamfer-L2 and F-score against the true mesh via
  :mod:`geofit.metrics`).

No NaN: every map is evaluated in float64 with PyTorch3D's clamps (and the additional guards of
:mod:`geofit.render.soft`); the solvers stop with status ``"nonfinite"`` (returning the last
finite parameters) should a value or gradient ever be non-finite, and every recorded history row
is checked.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._validate import as_rng, check_choice, check_positive
from ..structures import MultiViewDataset
from ..render.soft import SoftRasterizationSettings
from ..shapes import ico_sphere, subdivide
from ..structures import Mesh, TexturesVertex, as_mesh
from ._options import (
    Recipes,
    check_int,
    check_weights,
    method_name,
    recipe_name,
    warn_deprecated,
)
from ._progress import NoBar, progress_bar
from ._views_eval import ViewsEvaluator
from ._views_init import initial_mesh
from ._views_objective import (
    REG_TERMS,
    _ContourObjective,
    _lstsq_colors,
    _Objective,
    dataset_lights,
)
from .history import Clock, FitHistory, FitResult
from .large_steps import vertex_parameterization
from .solvers import adam, lbfgs_nlopt, lbfgs_scipy, sgd

__all__ = [
    "HULL_SILHOUETTE_WEIGHTS",
    "INITS",
    "RECIPES",
    "SILHOUETTE_LOSSES",
    "SILHOUETTE_METHODS",
    "TEXTURED_METHODS",
    "TUTORIAL_SILHOUETTE_WEIGHTS",
    "TUTORIAL_TEXTURED_WEIGHTS",
    "MultiViewData",
    "MultiViewSplit",
    "ViewsEvaluator",
    "ViewsFitResult",
    "cow_multiview_dataset",
    "fit_mesh_to_views",
    "render_multiview_dataset",
]

# deprecated names of the former dataset stack (one release)
from ._deprecated import (  # noqa: E402
    MultiViewData,
    MultiViewSplit,
    cow_multiview_dataset,
    render_multiview_dataset,
)

#: Silhouette-stage methods of :func:`fit_mesh_to_views` (``"none"`` skips the stage).
SILHOUETTE_METHODS = ("lbfgs", "lbfgs-nlopt", "sgd", "adam")
#: Silhouette losses: the soft silhouette's squared error, or the hard silhouette's contour
#: gradients (:mod:`geofit.render.soft.contour`).
SILHOUETTE_LOSSES = ("soft", "contour")
#: Textured-stage methods of :func:`fit_mesh_to_views`.
TEXTURED_METHODS = ("lstsq", "lbfgs", "sgd", "none")

#: Weights of the default fit's silhouette stage (at the tutorial's pixel size, see
#: :data:`TUTORIAL_PIXEL`): the tutorial's normal weight, edge and Laplacian 0.3 (the
#: large-steps parameterisation already smooths the steps; the smoothing still carries the
#: shape into directions no view sees: on the cow, held-out IoU 0.976 with these against 0.972
#: with edge 0, measured).
HULL_SILHOUETTE_WEIGHTS = {"silhouette": 1.0, "edge": 0.3, "normal": 0.01, "laplacian": 0.3}

#: The world size of a pixel in the tutorial's views (distance 2.7, field of view 60 degrees,
#: 128 px): the default recipe's edge and Laplacian weights are set at this pixel size and
#: scaled to the data's (squared and linearly, as the two terms scale with the edge length), so
#: that they weigh the same against the silhouettes at any object scale and image size.
TUTORIAL_PIXEL = 2.0 * 2.7 * math.tan(math.radians(30.0)) / 128

#: Recipes of :func:`fit_mesh_to_views`: the stage methods and their settings. ``"default"``
#: starts from the visual hull and remeshes as the surface moves; ``"sphere-lbfgs"`` is the
#: former default (L-BFGS on all views from the tutorial's ``ico_sphere(4)``).
RECIPES: dict[str, dict] = Recipes({
    "default": {"silhouette_method": "lbfgs", "silhouette_loss": "soft",
                "textured_method": "lstsq", "textured_init": "silhouette", "large_steps": 10.0,
                "init": "hull", "levels": [(0, 2), (0, 1)], "remesh_rounds": 2,
                "silhouette_iters": 120, "silhouette_weights": HULL_SILHOUETTE_WEIGHTS},
    "sphere-lbfgs": {"silhouette_method": "lbfgs", "silhouette_loss": "soft",
                     "textured_method": "lstsq", "textured_init": "silhouette",
                     "large_steps": None, "init": "sphere", "levels": None,
                     "remesh_rounds": 0, "silhouette_iters": 2000},
    "tutorial": {"silhouette_method": "sgd", "silhouette_loss": "soft",
                 "textured_method": "sgd", "textured_init": "sphere", "large_steps": None,
                 "init": "sphere", "levels": None, "remesh_rounds": 0, "silhouette_iters": 2000},
    "contour": {"silhouette_method": "adam", "silhouette_loss": "contour",
                "textured_method": "lstsq", "textured_init": "silhouette", "large_steps": 10.0,
                "init": "sphere", "levels": None, "remesh_rounds": 0, "silhouette_iters": 2000},
}, fit="fit_mesh_to_views")

#: Initialisations of :func:`fit_mesh_to_views` (or a Mesh).
INITS = ("hull", "sphere")

#: The tutorial's loss weights for the silhouette stage.
TUTORIAL_SILHOUETTE_WEIGHTS = {"silhouette": 1.0, "edge": 1.0, "normal": 0.01, "laplacian": 1.0}
#: The tutorial's loss weights for the textured stage.
TUTORIAL_TEXTURED_WEIGHTS = {"rgb": 1.0, "silhouette": 1.0, "edge": 1.0, "normal": 0.01,
                             "laplacian": 1.0}

_MAX_FACES = 4000  # the default's remeshing keeps at most about this many faces (full size)
_ADAM_PHASES = (1.0, 0.3, 0.1)  # lr factors of the contour method's Adam phases
_ADAM_LEVEL_DECAY = 0.3         # and per coarse-to-fine level
# the overall status of a fit is the first of these that a stage ended with
_STATUS_ORDER = ("nonfinite", "failed", "diverged", "callback", "stalled", "time_budget",
                 "max_eval", "max_iter", "converged")


# =========================================================================================
# Result
# =========================================================================================


@dataclass(kw_only=True)
class ViewsFitResult(FitResult):
    """Result of :func:`fit_mesh_to_views`.

    Attributes
    ----------
    mesh : Mesh
        The fitted mesh (with ``TexturesVertex`` when a textured stage ran).
    colors : (V, 3) float64 or None
        Fitted vertex colours.
    silhouette_mesh : Mesh
        The mesh after the silhouette stage.
    stages : list of dict
        Per stage: name, method, status, message, seconds, iterations, evaluations.
    init : str
        The initialisation used: ``"hull"`` (visual hull), ``"sphere"`` or ``"user"``.
    init_mesh : Mesh
        The starting mesh.
    topology : geofit.ops.TopologyReport
        Genus, boundary loops, parts, non-manifold edges and self-intersecting face pairs of
        the fitted mesh (a self-intersecting result says so in ``message``).
    """

    mesh: Mesh = None
    colors: np.ndarray | None = None
    silhouette_mesh: Mesh = None
    stages: list = field(default_factory=list)
    init: str = ""
    init_mesh: Mesh = None
    topology: Any = None

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d["init"] = self.init
        d["n_verts"] = self.mesh.n_verts if self.mesh is not None else 0
        if self.topology is not None:
            d["topology"] = self.topology.as_dict()
        return d


# =========================================================================================
# The fit
# =========================================================================================


def _stage_options(settings, silhouette_method, silhouette_loss, textured_method,
                   textured_init, large_steps):
    """The stage options in the current vocabulary: the recipe's where not given; the former
    ``"tutorial"`` and ``"contour"`` methods translated with a DeprecationWarning."""
    if silhouette_method == "tutorial":
        warn_deprecated("fit_mesh_to_views(silhouette_method='tutorial')",
                        "recipe='tutorial' or silhouette_method='sgd'", 5)
        silhouette_method = "sgd"
    elif silhouette_method == "contour":
        warn_deprecated("fit_mesh_to_views(silhouette_method='contour')",
                        "recipe='contour' or silhouette_method='adam', silhouette_loss='contour'",
                        5)
        silhouette_method, silhouette_loss = "adam", "contour"
    if textured_method == "tutorial":
        warn_deprecated("fit_mesh_to_views(textured_method='tutorial')",
                        "recipe='tutorial' or textured_method='sgd'", 5)
        textured_method = "sgd"
    sm = settings["silhouette_method"] if silhouette_method is None else silhouette_method
    if sm != "none":
        sm = method_name(sm, "silhouette_method", SILHOUETTE_METHODS + ("none",),
                         fit="fit_mesh_to_views", stacklevel=5)
    loss = settings["silhouette_loss"] if silhouette_loss is None else silhouette_loss
    check_choice(loss, "silhouette_loss", SILHOUETTE_LOSSES)
    if loss == "contour" and sm not in ("adam", "none"):
        raise ValueError(f"silhouette_loss: 'contour' gradients are not those of a smooth "
                         f"objective; expected silhouette_method='adam', got {sm!r}")
    tm = settings["textured_method"] if textured_method is None else textured_method
    tm = method_name(tm, "textured_method", TEXTURED_METHODS, fit="fit_mesh_to_views",
                     stacklevel=5)
    ti = settings["textured_init"] if textured_init is None else textured_init
    check_choice(ti, "textured_init", ("silhouette", "sphere"))
    if isinstance(large_steps, str) and large_steps == "auto":
        large_steps = settings["large_steps"]
    return sm, loss, tm, ti, large_steps


def _levels(levels, mesh_level_final: int, image_size):
    """Coarse-to-fine schedule: list of (subdivisions to apply before, downsample factor)."""
    if levels is None:
        return [(0, 1)]
    out = []
    for i, lv in enumerate(levels):
        try:
            sub, fac = int(lv[0]), int(lv[1])
        except (TypeError, ValueError, IndexError):
            raise ValueError(f"levels[{i}]: expected (subdivisions, downsample factor), got "
                             f"{lv!r}") from None
        if sub < 0 or fac < 1:
            raise ValueError(f"levels[{i}]: expected subdivisions >= 0 and factor >= 1, got "
                             f"{lv!r}")
        out.append((sub, fac))
    return out


@dataclass
class _Recorder:
    """Records history rows, checks finiteness, runs the observer's evaluation at checkpoints."""

    h: FitHistory
    clock: Clock
    evaluate: Callable | None
    eval_every: float
    callback: Callable | None
    stage: int
    step0: int
    bar: object = field(default_factory=NoBar)
    last_eval: float = -math.inf
    steps: int = 0

    def __call__(self, obj: _Objective, info, mesh_fn, colors_fn, force_eval=False) -> bool:
        self.steps += 1
        last = getattr(obj, "_cache", {}).get(np.asarray(info.x).tobytes(), obj.last)
        terms = last.get("terms", {})
        value = float(info.value)
        step = self.step0 + self.steps
        seconds = self.clock.elapsed()
        metrics = None
        if self.evaluate is not None and (force_eval or seconds - self.last_eval
                                          >= self.eval_every):
            with self.clock.paused():
                metrics = self.evaluate(mesh_fn(info.x), colors_fn(info.x))
            self.last_eval = seconds
        if self.h.terms and set(terms) != set(self.h.terms):
            terms = {k: terms.get(k, 0.0) for k in self.h.terms}
        self.h.record(step, seconds, value, terms, metrics, n_params=len(info.x),
                      stage=self.stage)
        with self.clock.paused():
            self.bar.update(1)
            if self.steps % 10 == 1:
                self.bar.set_postfix(loss=f"{value:.4g}", stage=self.stage)
        if self.callback is not None:
            with self.clock.paused():
                stop = self.callback({"stage": self.stage, "step": step, "seconds": seconds,
                                      "value": value, "terms": dict(terms),
                                      "grad_norm": last.get("grad_norm", float("nan")),
                                      "x": info.x, "metrics": metrics})
            return bool(stop)
        return False


def fit_mesh_to_views(dataset: MultiViewDataset, *, init: Mesh | str | None = None,
                      recipe: str = "default", silhouette_method: str | None = None,
                      silhouette_loss: str | None = None, textured_method: str | None = None,
                      silhouette_weights: Mapping[str, float] | None = None,
                      textured_weights: Mapping[str, float] | None = None,
                      silhouette_iters: int | None = None, textured_iters: int = 2000,
                      silhouette_time: float | None = None, textured_time: float | None = None,
                      large_steps: float | str | None = "auto", levels="auto",
                      remesh_rounds: int | None = None, edge_px: float = 3.0,
                      textured_init: str | None = None, views_per_step: int = 2,
                      lr: float = 1.0, momentum: float = 0.9, adam_lr: float = 0.01,
                      faces_per_pixel: int = 50, color_reg: float = 1e-4,
                      contour_threshold: float | None = 0.9,
                      evaluate: Callable | None = None, eval_every: float = 5.0,
                      callback: Callable | None = None, seed=0,
                      progress: bool = True) -> ViewsFitResult:
    """Fit a mesh to multi-view silhouettes, then its vertex colours (tutorial 4).

    The default starts from the visual hull of the silhouettes (its genus and parts), and
    alternates L-BFGS on the soft silhouettes of all views (large steps, half then full
    resolution) with remeshing to edges of ``edge_px`` pixels; the colours then come from one
    sparse least-squares solve.

    Parameters
    ----------
    dataset : MultiViewDataset
        Training views: cameras, soft silhouettes and (for a textured stage) RGB images.
    init : {"hull", "sphere"} or Mesh, optional
        Starting mesh (default: the recipe's). ``"hull"``: the visual hull of the silhouettes
        (carved at their 0.5 level, marching cubes, decimated to
        edges of ``2 edge_px`` pixels; :mod:`geofit.fit._views_init`). ``"sphere"``: the
        tutorial's ``ico_sphere(4)`` (``ico_sphere(4 - subdivisions)`` when ``levels``
        subdivide). A Mesh is used as given. The result's ``init`` says which.
    recipe : {"default", "sphere-lbfgs", "tutorial", "contour"}
        Named settings (:data:`RECIPES`) for the options left at None / "auto": ``"default"``
        the visual hull, large steps, coarse-to-fine and remeshing as above; ``"sphere-lbfgs"``
        (the former default) L-BFGS on the soft silhouettes of all views from the ico-sphere;
        ``"tutorial"`` the tutorial's SGD (two random views per step) for both stages, the
        textured one from the sphere; ``"contour"`` Adam on the hard silhouette's contour
        gradients, large steps 10.
    silhouette_method : {"lbfgs", "lbfgs-nlopt", "sgd", "adam", "none"}, optional
        Solver of the silhouette stage (see the module docstring); ``"sgd"`` draws
        ``views_per_step`` random views per step, the others use all views.
    silhouette_loss : {"soft", "contour"}, optional
        The soft silhouettes' squared error, or the hard silhouette's contour gradients
        (``"adam"`` only).
    textured_method : {"lstsq", "lbfgs", "sgd", "none"}, optional
        Method of the textured stage.
    silhouette_weights, textured_weights : dict, optional
        Term weights (defaults: the recipe's; :data:`HULL_SILHOUETTE_WEIGHTS` for
        ``"default"``, else the tutorial's, :data:`TUTORIAL_SILHOUETTE_WEIGHTS`, and
        :data:`TUTORIAL_TEXTURED_WEIGHTS`). With ``recipe="default"`` the silhouette stage's
        edge and Laplacian weights hold at the tutorial's pixel size (:data:`TUTORIAL_PIXEL`)
        and are scaled by ``(TUTORIAL_PIXEL / p)**2`` and ``TUTORIAL_PIXEL / p`` for the data's
        pixel size ``p``.
    silhouette_iters, textured_iters : int
        Iteration budgets per stage (SGD / Adam steps or L-BFGS iterations; for coarse-to-fine
        split over the levels in proportion to their downsampling factor, then evenly over a
        level's remeshing rounds). ``silhouette_iters`` None: the
        recipe's (120 for ``"default"``, 2000 for the others).
    silhouette_time, textured_time : float, optional
        Time budgets in seconds per stage (solver time).
    large_steps : float, "auto" or None
        ``lambda`` of the large-steps parameterisation (None: plain vertex positions; "auto":
        the recipe's).
    levels : sequence of (int, int), optional
        Coarse-to-fine schedule for the L-BFGS and contour methods: per level the number of
        midpoint subdivisions to apply first and the image downsampling factor, e.g.
        ``[(0, 2), (1, 1)]`` = start mesh at half resolution, then subdivide once at full
        resolution. ``"auto"``: the recipe's (``[(0, 2), (0, 1)]`` for ``"default"``); None:
        one level at full resolution. The edge, normal and Laplacian
        weights of a level with ``s`` subdivisions still to come are multiplied by ``4**-s``
        (the three terms scale with the squared edge length).
    remesh_rounds : int, optional
        Remesh-and-solve rounds per level (0: no remeshing; None: the recipe's, 2 for
        ``"default"``). Before each solve the mesh is remeshed (:func:`geofit.ops.remesh`:
        split, collapse, flip; manifold kept) to edges of ``edge_px`` pixels of that level's
        images (at most a fifteenth of the initial mesh's bounding-box diagonal, and long enough
        to keep about 4000 faces at full resolution, 1000 at half: a bounded time per
        evaluation).
    edge_px : float
        Target edge length of the remeshing in pixels (measured at the initial mesh's centre).
    textured_init : {"silhouette", "sphere"}, optional
        Start the textured stage from the silhouette result (default) or, as the tutorial
        does, from the initial mesh ``init``.
    views_per_step : int
        Random views per step of the tutorial recipe (2).
    lr, momentum : float
        SGD settings of the tutorial recipe (1.0, 0.9).
    adam_lr : float
        Step size of the contour method's Adam at the first level (each level ``l`` runs three
        phases with step sizes ``a``, ``a * 0.3`` and ``a * 0.1``, ``a = adam_lr * 0.3**l``,
        splitting its iterations and time).
    faces_per_pixel : int
        K of the soft rasterizer (50).
    contour_threshold : float or None
        The contour method compares the mesh's hard silhouette with the targets binarised at
        this level (None: the targets as they are, compared at 0.5). The tutorial's soft
        silhouettes exceed 0.5 up to a pixel outside the cow's outline; on its 20 views the 0.9
        level misclassifies the fewest pixels against the true hard masks (3514 of 327680,
        against 5478 at 0.5 and 3311 at 0.95, which loses interior pixels), hence the default.
    color_reg : float
        Weight of the Laplacian smoothness of the colours in the ``lstsq`` solve (fills vertices
        no view sees).
    evaluate : callable, optional
        ``evaluate(mesh, colors) -> dict`` run at checkpoints every ``eval_every`` seconds with
        the clock paused (e.g. a :class:`ViewsEvaluator`).
    callback : callable, optional
        ``callback(record: dict) -> bool`` after every step with ``stage``, ``step``,
        ``seconds``, ``value``, ``terms``, ``grad_norm``, ``x``, ``metrics``; True stops the
        stage.
    seed : int or numpy.random.Generator
        For the random views of the stochastic recipes.
    progress : bool
        Show a tqdm progress bar (on stderr; one tick per iteration of either stage).

    Returns
    -------
    ViewsFitResult
        ``status`` is the most serious of the stages' statuses, in the order ``nonfinite``,
        ``failed``, ``diverged``, ``callback``, ``stalled``, ``time_budget``, ``max_eval``,
        ``max_iter``, ``converged``; ``stages`` has each stage's own status and message.
    """
    plan = _ViewsPlan.validate(
        dataset, init=init, recipe=recipe, silhouette_method=silhouette_method,
        silhouette_loss=silhouette_loss, textured_method=textured_method,
        silhouette_weights=silhouette_weights, textured_weights=textured_weights,
        silhouette_iters=silhouette_iters, textured_iters=textured_iters,
        silhouette_time=silhouette_time, textured_time=textured_time,
        large_steps=large_steps, levels=levels, textured_init=textured_init,
        views_per_step=views_per_step, lr=lr, momentum=momentum, adam_lr=adam_lr,
        faces_per_pixel=faces_per_pixel, color_reg=color_reg,
        contour_threshold=contour_threshold, remesh_rounds=remesh_rounds, edge_px=edge_px)
    run = _ViewsRun(plan, seed=seed, evaluate=evaluate, eval_every=eval_every,
                    callback=callback, progress=progress)
    initial_mesh(plan, run)
    sil_mesh = _silhouette_stage(plan, run) if plan.silhouette_method != "none" else plan.init
    mesh, colors = sil_mesh, None
    if plan.textured_method != "none" and (not run.stages or run.stages[-1]["status"] not in
                                           ("nonfinite", "failed")):
        mesh, colors = _textured_stage(plan, run, sil_mesh)
    return _views_result(plan, run, mesh, colors, sil_mesh)


@dataclass
class _ViewsPlan:
    """The validated options of one :func:`fit_mesh_to_views` call (recipe resolved)."""

    views: MultiViewDataset
    init: Mesh
    recipe: str
    silhouette_method: str
    silhouette_loss: str
    textured_method: str
    textured_init: str
    silhouette_weights: dict
    textured_weights: dict
    silhouette_iters: int
    textured_iters: int
    silhouette_time: float | None
    textured_time: float | None
    large_steps: float | None
    levels: list
    views_per_step: int
    lr: float
    momentum: float
    adam_lr: float
    faces_per_pixel: int
    color_reg: float
    contour_threshold: float | None
    init_name: str = "user"
    remesh_rounds: int = 0
    edge_px: float = 3.0
    init_info: dict = field(default_factory=dict)

    @classmethod
    def validate(cls, dataset, *, init, recipe, silhouette_method, silhouette_loss,
                 textured_method, textured_init, silhouette_weights, textured_weights,
                 silhouette_iters, textured_iters, large_steps, levels, views_per_step,
                 faces_per_pixel, **rest) -> _ViewsPlan:
        """Check every option once and fill in the recipe's."""
        if not isinstance(dataset, MultiViewDataset):
            raise TypeError(f"dataset: expected a MultiViewDataset, got {type(dataset)!r}")
        dataset.require_silhouettes("fit_mesh_to_views")
        recipe = recipe_name(recipe, RECIPES, fit="fit_mesh_to_views")
        rec = RECIPES[recipe]
        silhouette_method, silhouette_loss, textured_method, textured_init, large_steps = \
            _stage_options(RECIPES[recipe], silhouette_method, silhouette_loss,
                           textured_method, textured_init, large_steps)
        if silhouette_method == "none" and textured_method == "none":
            raise ValueError("silhouette_method and textured_method are both 'none': nothing "
                             "to fit")
        if textured_method != "none" and dataset.images is None:
            raise ValueError("dataset: a textured stage needs RGB images (dataset.images is "
                             "None)")
        sw = check_weights(silhouette_weights,
                           rec.get("silhouette_weights", TUTORIAL_SILHOUETTE_WEIGHTS),
                           "silhouette_weights")
        if silhouette_iters is None:
            silhouette_iters = rec["silhouette_iters"]
        remesh_rounds = rec["remesh_rounds"] if rest["remesh_rounds"] is None else \
            check_int(rest["remesh_rounds"], "remesh_rounds", 0)
        edge_px = check_positive(rest["edge_px"], "edge_px")
        tw = check_weights(textured_weights, TUTORIAL_TEXTURED_WEIGHTS, "textured_weights")
        for nm, v in (("silhouette_iters", silhouette_iters),
                      ("textured_iters", textured_iters), ("views_per_step", views_per_step),
                      ("faces_per_pixel", faces_per_pixel)):
            check_int(v, nm)
        if views_per_step > len(dataset):
            raise ValueError(f"views_per_step: expected at most {len(dataset)} (the number of "
                             f"views), got {views_per_step}")
        if large_steps is not None:
            large_steps = check_positive(large_steps, "large_steps")
        if isinstance(levels, str) and levels == "auto":
            levels = rec["levels"]
        lv = _levels(levels, 4, dataset.image_size)
        init = rec["init"] if init is None else init
        if isinstance(init, str):
            check_choice(init, "init", INITS)
            init_name = init
            init = ico_sphere(max(4 - sum(s for s, _ in lv), 0)) if init == "sphere" else None
        else:
            init_name = "user"
            init = as_mesh(init, "init")  # a geofit, trimesh or Open3D mesh
        H, W = dataset.image_size
        for _, f_ in lv:
            if H % f_ or W % f_:
                raise ValueError(f"levels: factor {f_} does not divide the image size {(H, W)}")
        return cls(dataset, init, recipe, silhouette_method, silhouette_loss, textured_method,
                   textured_init, sw, tw, silhouette_iters, textured_iters,
                   rest["silhouette_time"], rest["textured_time"], large_steps, lv,
                   views_per_step, rest["lr"], rest["momentum"], rest["adam_lr"],
                   faces_per_pixel, rest["color_reg"], rest["contour_threshold"],
                   init_name, remesh_rounds, edge_px)

    def settings(self, size, persp=None) -> SoftRasterizationSettings:
        """The tutorial's soft rasterization at ``size`` with this fit's K, storing fragments
        in float64: the fit's gradients are solved by L-BFGS line searches (DESIGN: float64
        where gradients are checked and solved), and its benchmark figures were measured so."""
        return SoftRasterizationSettings.tutorial(size, faces_per_pixel=self.faces_per_pixel,
                                                  perspective_correct=persp, dtype=np.float64)


class _ViewsRun:
    """The state shared by the stages of one fit: clock, history, progress bar, counters."""

    def __init__(self, plan: _ViewsPlan, *, seed, evaluate, eval_every, callback, progress):
        self.rng = as_rng(seed)
        self.clock = Clock()
        self.history = FitHistory()
        self.evaluate, self.eval_every, self.callback = evaluate, eval_every, callback
        total = (plan.silhouette_iters if plan.silhouette_method != "none" else 0) + \
            (plan.textured_iters if plan.textured_method in ("sgd", "lbfgs") else 0)
        self.bar = progress_bar(progress, total, f"fit_mesh_to_views[{plan.silhouette_method}"
                                                 f"+{plan.textured_method}]")
        self.stages: list = []
        self.n_iterations = 0
        self.n_evaluations = 0
        self.step = 0

    def recorder(self, stage_index: int) -> _Recorder:
        """The per-step recorder of one solve (history, evaluation, callback, bar)."""
        return _Recorder(self.history, self.clock, self.evaluate, self.eval_every,
                         self.callback, stage_index, self.step, self.bar)

    def add(self, res, rec: _Recorder) -> None:
        """Count a finished solve's steps, iterations and evaluations."""
        self.step += rec.steps
        self.n_iterations += res.n_iterations
        self.n_evaluations += res.n_evaluations


def _silhouette_stage(plan: _ViewsPlan, run: _ViewsRun) -> Mesh:
    """Deform the mesh to the silhouettes, level by level (remeshing before each solve when
    ``remesh_rounds``); returns the mesh."""
    from ._views_init import remesh_to_length

    t_stage = run.clock.elapsed()
    # the tutorial's SGD (random views per step) runs one level at full resolution
    sub_levels = [(0, 1)] if plan.silhouette_method == "sgd" else plan.levels
    rounds = max(plan.remesh_rounds, 1)
    n_solves = len(sub_levels) * rounds
    # iterations shared in proportion to the downsampling factor: the cheap coarse levels
    # get more of them
    total_fac = sum(f_ for _, f_ in sub_levels)
    mesh = plan.init
    status, message = "max_iter", ""
    for li, (sub, fac) in enumerate(sub_levels):  # coarse-to-fine levels
        for _ in range(sub):  # subdivisions
            mesh = subdivide(mesh)
        data = plan.views.downsample(fac)
        # the regularisers scale with the squared edge length (1/4 per subdivision): on a
        # coarse level they get the weight that gives them their final-level magnitude
        later = sum(s_ for s_, _ in sub_levels[li + 1:])
        weights = {k: (v * 0.25 ** later if k in REG_TERMS else v)
                   for k, v in plan.silhouette_weights.items()}
        if plan.recipe == "default":  # weights set in pixels (TUTORIAL_PIXEL)
            r = TUTORIAL_PIXEL / plan.init_info["pixel_size"]
            weights["edge"] *= r * r
            weights["laplacian"] *= r
        for ri in range(rounds):  # remesh-and-solve rounds
            if plan.remesh_rounds:
                # edge_px pixels, at most max_edge; at least the length that keeps the face
                # count under _MAX_FACES / fac^2 (a bounded time per evaluation)
                floor = math.sqrt(float(mesh.face_areas.sum()) * fac * fac / (0.433 * _MAX_FACES))
                mesh = remesh_to_length(mesh, max(min(plan.edge_px * fac * plan.init_info[
                    "pixel_size"], plan.init_info["max_edge"]), floor))
            k = li * rounds + ri
            budget = None
            if plan.silhouette_time is not None:
                remaining = plan.silhouette_time - (run.clock.elapsed() - t_stage)
                budget = max(remaining / (n_solves - k), 1e-3)
            obj = _silhouette_objective(plan, run, mesh, data, weights)
            iters = max(1, round(plan.silhouette_iters * fac / (rounds * total_fac)))
            mesh, res = _silhouette_solve(plan, run, obj, mesh, li, iters, budget)
            status, message = res.status, res.message
            run.history.note(run.step, run.clock.elapsed(),
                             f"silhouette level {li} round {ri}: {res.status}",
                             n_verts=mesh.n_verts, image_size=list(data.image_size))
            if res.status in ("nonfinite", "failed", "callback"):
                break
        if res.status in ("nonfinite", "failed", "callback"):
            break
    run.stages.append({"name": "silhouette", "method": plan.silhouette_method,
                       "status": status, "message": message,
                       "seconds": run.clock.elapsed() - t_stage})
    return mesh


def _silhouette_objective(plan: _ViewsPlan, run: _ViewsRun, mesh: Mesh,
                          data: MultiViewDataset, weights: dict):
    """The objective of one level: soft silhouettes, or the contour term."""
    param = vertex_parameterization(mesh, plan.large_steps)
    if plan.silhouette_loss == "contour":
        from ..render.soft.contour import ContourSilhouetteLoss

        closs = ContourSilhouetteLoss(data.cameras, data.silhouettes,
                                      threshold=plan.contour_threshold)
        return _ContourObjective(mesh, closs, weights, param)
    vps = plan.views_per_step if plan.silhouette_method == "sgd" else None
    return _Objective(mesh, data, weights, textured=False, param=param,
                      settings=plan.settings(data.image_size), views_per_step=vps, rng=run.rng)


def _silhouette_solve(plan: _ViewsPlan, run: _ViewsRun, obj, mesh: Mesh, li: int,
                      iters: int, budget: float | None):
    """Run the silhouette method on one level's objective; returns the mesh and the result."""
    rec = run.recorder(li)
    x0 = obj.param.to_params(mesh.verts).ravel()

    def cb(info, obj=obj, rec=rec):
        return rec(obj, info, lambda x: obj.base.update_verts(obj.split(x)[0]), lambda x: None)

    method, clock = plan.silhouette_method, run.clock
    if method == "sgd":
        res = sgd(obj, x0, lr=plan.lr, momentum=plan.momentum, n_iter=iters,
                  time_budget=budget, callback=cb, clock=clock)
    elif method == "lbfgs":
        res = lbfgs_scipy(obj, x0, max_iter=iters, time_budget=budget, callback=cb, clock=clock)
    elif method == "lbfgs-nlopt":
        res = lbfgs_nlopt(obj, x0, max_eval=iters, time_budget=budget, callback=cb, clock=clock)
    else:
        res = _adam_phases(obj, x0, lr=plan.adam_lr, decay=_ADAM_LEVEL_DECAY ** li,
                           iters=iters, budget=budget, callback=cb, clock=clock)
    run.add(res, rec)
    return obj.base.update_verts(obj.split(res.x)[0]), res


def _adam_phases(obj, x0, *, lr, decay, iters, budget, callback, clock):
    """Adam with a step decay: three phases at lr, lr / 3 and lr / 10 (the contour gradient
    does not vanish at the optimum, pixel noise stays; smaller steps settle it), splitting the
    iterations and the time budget."""
    x, n_it, n_ev = x0, 0, 0
    t_level = clock.elapsed()
    for k, factor in enumerate(_ADAM_PHASES):  # lr phases
        b = None
        if budget is not None:
            left = budget - (clock.elapsed() - t_level)
            b = max(left / (len(_ADAM_PHASES) - k), 1e-3)
        res = adam(obj, x, lr=lr * factor * decay, n_iter=max(1, iters // len(_ADAM_PHASES)),
                   time_budget=b, callback=callback, clock=clock)
        x = res.x
        n_it += res.n_iterations
        n_ev += res.n_evaluations
        if res.status in ("nonfinite", "diverged", "callback"):
            break
    return replace(res, n_iterations=n_it, n_evaluations=n_ev)


def _textured_stage(plan: _ViewsPlan, run: _ViewsRun, sil_mesh: Mesh):
    """Fit the vertex colours (and, for sgd / lbfgs, the positions); returns the textured
    mesh and the colours."""
    t_stage = run.clock.elapsed()
    tex_mesh = sil_mesh if plan.textured_init == "silhouette" else plan.init
    if plan.textured_method == "sgd":
        tex_mesh, colors, res = _textured_solve(plan, run, tex_mesh, None)
        status, message = res.status, res.message
    else:
        colors = _lstsq_colors(tex_mesh, plan.views, plan.color_reg)
        status, message = "converged", "colours by sparse least squares on the hard render"
        if run.evaluate is not None:
            with run.clock.paused():
                metrics = run.evaluate(tex_mesh, colors)
            h = run.history
            h.checkpoint(max(run.step, h.steps[-1] if h.steps else 0),
                         max(run.clock.elapsed(), h.seconds[-1] if h.seconds else 0.0), metrics)
        if plan.textured_method == "lbfgs":
            tex_mesh, colors, res = _textured_solve(plan, run, tex_mesh, colors)
            status, message = res.status, res.message
    mesh = Mesh(tex_mesh.verts, tex_mesh.faces, TexturesVertex(np.clip(colors, 0.0, 1.0)))
    run.stages.append({"name": "textured", "method": plan.textured_method, "status": status,
                       "message": message, "seconds": run.clock.elapsed() - t_stage})
    return mesh, colors


def _textured_solve(plan: _ViewsPlan, run: _ViewsRun, tex_mesh: Mesh, colors):
    """Positions and colours by the tutorial's SGD (``colors`` None: from 0.5, random views)
    or by joint L-BFGS over all views from ``colors``."""
    sgd_ = colors is None
    param = vertex_parameterization(tex_mesh, None if sgd_ else plan.large_steps)
    obj = _Objective(tex_mesh, plan.views, plan.textured_weights, textured=True, param=param,
                     settings=plan.settings(plan.views.image_size, persp=False),
                     views_per_step=plan.views_per_step if sgd_ else None,
                     rng=run.rng if sgd_ else None)
    c0 = np.full(3 * tex_mesh.n_verts, 0.5) if sgd_ else colors.ravel()
    x0 = np.concatenate([param.to_params(tex_mesh.verts).ravel(), c0])
    rec = run.recorder(100)

    def cb(info, obj=obj, rec=rec):
        return rec(obj, info, lambda x: obj.base.update_verts(obj.split(x)[0]),
                   lambda x: obj.split(x)[1])

    if sgd_:
        res = sgd(obj, x0, lr=plan.lr, momentum=plan.momentum, n_iter=plan.textured_iters,
                  time_budget=plan.textured_time, callback=cb, clock=run.clock)
    else:
        res = lbfgs_scipy(obj, x0, max_iter=plan.textured_iters,
                          time_budget=plan.textured_time, callback=cb, clock=run.clock)
    v, colors = obj.split(res.x)
    run.add(res, rec)
    return tex_mesh.update_verts(v), colors, res


def _views_result(plan: _ViewsPlan, run: _ViewsRun, mesh: Mesh, colors,
                  sil_mesh: Mesh) -> ViewsFitResult:
    """The overall status (the most serious of the stages') and the result."""
    run.bar.close()
    statuses = [s["status"] for s in run.stages]
    final = next(s for s in _STATUS_ORDER if s in statuses)
    from ..ops import topology

    msg = "; ".join(f"{s['name']} ({s['method']}): {s['status']} - {s['message']}"
                    for s in run.stages)
    with run.clock.paused():
        topo = topology(Mesh(mesh.verts, mesh.faces))
    msg = f"init: {plan.init_info.get('description', plan.init_name)}; {msg}; result: " \
          f"{topo.describe()}"
    if topo.n_self_intersecting_pairs > 0:
        msg += " (the fitted surface self-intersects)"
    return ViewsFitResult(status=final, message=msg, history=run.history,
                          n_params=mesh.n_verts * (6 if colors is not None else 3),
                          seconds=run.clock.elapsed(), cpu_seconds=run.clock.cpu_elapsed(),
                          n_iterations=run.n_iterations, n_evaluations=run.n_evaluations,
                          mesh=mesh, colors=colors, silhouette_mesh=sil_mesh,
                          stages=run.stages,
                          method=f"{plan.silhouette_method}+{plan.textured_method}",
                          recipe=plan.recipe, init=plan.init_name, init_mesh=plan.init,
                          topology=topo)
