"""The six workflows of PyTorch3D's introductory tutorials, end to end, in one run.

:func:`run_tutorials` runs the steps below on the default data (the tutorial files when
``GEOFIT_DATA`` or the cache holds them, else geofit's procedural stand-ins), writes every image,
mesh (OBJ), volume (npz), history (JSON) and chart into one folder, and then the report
(``report.html``, ``report.md``, ``report.json``, see :mod:`geofit.report`). Each step is a
function ``step_<name>(out, size="default", *, progress=True, seed=0) -> StepResult`` that calls
the workflow's public API:

* ``fit_mesh`` -- deform_source_mesh_to_target_mesh: :func:`geofit.fit.fit_mesh`;
* ``render_mesh`` -- render_textured_meshes: :class:`geofit.render.MeshRenderer`;
* ``render_points`` -- render_colored_points: :class:`geofit.render.points.PointsRenderer`;
* ``fit_views`` -- fit_textured_mesh: :func:`geofit.fit.views.fit_mesh_to_views`;
* ``fit_volume`` -- fit_textured_volume: :func:`geofit.fit.volume.fit_volume`;
* ``nerf`` -- fit_simple_neural_radiance_field: :func:`geofit.fit.nerf.fit_nerf`.

Sizes: ``"full"`` is the tutorials' own size (image sizes, views, iterations); ``"default"`` is
reduced so that the whole run takes a few minutes on two cores; ``"tiny"`` is for tests (seconds
per step, numbers not meaningful). Every fitting step runs PyTorch3D's recipe (ported: same
model, losses, optimiser and schedule, at the step's size) next to geofit's own method, on the
same data, and measures both the same way.

A step that raises is recorded as ``"failed: <exception>: <message>"`` (with the traceback in
``<out>/<step>/error.txt``); it is never silently dropped.
"""
from __future__ import annotations

import json
import math
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._validate import check_choice
from .fit.history import FitHistory, _json_safe
from .viz import Series, image_panel, plot_accuracy_vs_time, plot_model_sizes, save_png

__all__ = [
    "SIZES",
    "STEPS",
    "StepResult",
    "TutorialsRun",
    "run_step",
    "run_tutorials",
    "step_fit_mesh",
    "step_fit_views",
    "step_fit_volume",
    "step_nerf",
    "step_render_mesh",
    "step_render_points",
]

#: Run sizes: test-sized, the reduced default, the tutorials' own.
SIZES = ("tiny", "default", "full")

# the two columns of the report's summary table
_P3D = "PyTorch3D's recipe (run by geofit)"
_GF = "geofit's method"


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------


@dataclass
class StepResult:
    """What one workflow produced: images, numbers, model sizes, stability, files.

    Attributes
    ----------
    name : str
        Step key (``"fit_mesh"``, ...).
    title : str
        Heading of its report section.
    tutorial : str
        The PyTorch3D tutorial it reproduces.
    status : str
        ``"ok"`` or ``"failed: <exception>: <message>"``.
    seconds : float
        Wall time of the whole step (set-up, fits, evaluation, figures).
    size : str
        One of :data:`SIZES`.
    description : str
        One paragraph: what was run and how it was measured.
    config : dict
        The step's settings (image sizes, views, iterations, ...).
    images : dict str -> Path
        Result images (PNG), by label.
    targets : dict str -> Path
        Target / reference images (PNG), by label.
    comparison : Path or None
        One PNG with the targets next to the results.
    comparison_caption : str
        Its caption.
    charts : dict str -> Path
        Charts (PNG) by caption: the speed-accuracy chart first.
    metrics : list of dict
        One row per method: status, seconds, accuracy.
    param_counts : list of dict
        One row per method: the free parameters of its model (or the scene size of a render).
    stability : list of dict
        One row per (method, failure case): the outcome (``converged``, ``stopped: <status>``,
        ``ok``, or ``failed: <exception>: <message>``) and what came out.
    methods : list of dict
        One benchmark-style record per method (``name``, ``label``, ``status``, ``message``,
        ``config``, ``final``, ``curve`` with ``seconds`` and one list per metric).
    histories : dict str -> FitHistory
        The fits' histories, by method.
    files : dict str -> Path
        Other outputs: meshes (OBJ), volumes (npz), histories (JSON).
    headline : dict
        Short summary cells for the report's overview table.
    notes : list of str
        Remarks (data used, what was not run and why).
    """

    name: str
    title: str
    tutorial: str
    status: str = "ok"
    seconds: float = 0.0
    size: str = "default"
    description: str = ""
    config: dict = field(default_factory=dict)
    images: dict = field(default_factory=dict)
    targets: dict = field(default_factory=dict)
    comparison: Path | None = None
    comparison_caption: str = ""
    charts: dict = field(default_factory=dict)
    metrics: list = field(default_factory=list)
    param_counts: list = field(default_factory=list)
    stability: list = field(default_factory=list)
    methods: list = field(default_factory=list)
    histories: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)
    headline: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True unless the step failed."""
        return not self.status.startswith("failed")

    def method_records(self) -> list[dict]:
        """The benchmark-style method records, each tagged with the step name."""
        return [{"step": self.name, **m} for m in self.methods]

    def to_dict(self, out: Path | None = None) -> dict:
        """JSON-ready summary (paths relative to ``out`` when given)."""
        def rel(p):
            p = Path(p)
            if out is not None:
                try:
                    return p.resolve().relative_to(Path(out).resolve()).as_posix()
                except ValueError:
                    pass
            return str(p)

        return _json_safe({
            "name": self.name, "title": self.title, "tutorial": self.tutorial,
            "status": self.status, "seconds": self.seconds, "size": self.size,
            "config": self.config, "metrics": self.metrics, "param_counts": self.param_counts,
            "stability": self.stability, "headline": self.headline, "notes": self.notes,
            "images": {k: rel(v) for k, v in self.images.items()},
            "targets": {k: rel(v) for k, v in self.targets.items()},
            "comparison": None if self.comparison is None else rel(self.comparison),
            "charts": {k: rel(v) for k, v in self.charts.items()},
            "files": {k: rel(v) for k, v in self.files.items()},
        })


@dataclass
class TutorialsRun:
    """The result of :func:`run_tutorials`.

    Attributes
    ----------
    steps : list of StepResult
    seconds : float
        Total wall time.
    out : Path
        The output folder.
    report : dict
        ``{"html": Path, "md": Path, "json": Path}``, and ``"gallery"`` (list of Path) when
        a gallery was written.
    charts : dict str -> Path
        Charts over all steps (parameter counts).
    """

    steps: list
    seconds: float
    out: Path
    report: dict
    charts: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when every step ran."""
        return all(s.ok for s in self.steps)


# --------------------------------------------------------------------------------------------
# Shared helpers
# --------------------------------------------------------------------------------------------


def _pick(size: str, tiny, default, full):
    return {"tiny": tiny, "default": default, "full": full}[size]


def _method(name: str, label: str, *, seconds=(), curve=None, final=None, status="",
            message="", config=None) -> dict:
    """A benchmark-style method record (the layout of benchmarks/_harness.py's MethodRun)."""
    return {"name": name, "label": label, "status": status, "message": message,
            "config": dict(config or {}), "final": dict(final or {}),
            "curve": {"seconds": [float(s) for s in seconds],
                      **{k: [float(x) for x in v] for k, v in (curve or {}).items()}}}


def _series(methods: Sequence[dict]) -> list[Series]:
    return [Series(m["label"], m["curve"]["seconds"],
                   {k: v for k, v in m["curve"].items() if k != "seconds"}) for m in methods]


def _failure(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else "(no message)"
    return f"failed: {type(exc).__name__}: {msg}"


def _try(fn: Callable[..., Any], *args, **kwargs) -> tuple[Any, str | None]:
    """``(fn(*args, **kwargs), None)`` or ``(None, "failed: <exception>: <message>")``."""
    try:
        return fn(*args, **kwargs), None
    except Exception as exc:  # noqa: BLE001 - stability rows report every failure
        return None, _failure(exc)


class _NoBar:
    def update(self, n=1):
        pass

    def set_postfix_str(self, s="", refresh=True):
        pass

    def close(self):
        pass


def _bar(progress: bool, total: int, desc: str):
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, leave=False, dynamic_ncols=True)


def _cameras(dist, elev, azim, *, ortho: bool = False, **kw):
    from .cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform

    R, T = look_at_view_transform(dist, elev, azim)
    if ortho:
        return FoVOrthographicCameras(R=R, T=T, **kw)
    return FoVPerspectiveCameras(R=R, T=T, **kw)


def _shade_mesh(mesh, cameras, image_size: int, *, color=(0.72, 0.75, 0.8), light=(2.0, 2.0, 2.0),
                background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(N, H, W, 3) Phong render of an untextured mesh in a flat colour (one per camera)."""
    from .render import (
        BlendParams,
        HardPhongShader,
        MeshRasterizer,
        MeshRenderer,
        PointLights,
        RasterizationSettings,
        TexturesFlat,
    )
    from .structures import Mesh

    m = Mesh(mesh.verts, mesh.faces, TexturesFlat(list(color)))
    n = len(cameras)
    renderer = MeshRenderer(MeshRasterizer(cameras, RasterizationSettings(image_size=image_size)),
                            HardPhongShader(lights=PointLights(location=[list(light)]),
                                            blend_params=BlendParams(background_color=background)))
    return np.asarray(renderer(m.extend(n) if n > 1 else m)[..., :3], dtype=np.float64)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a) > 0.5, np.asarray(b) > 0.5
    union = int((a | b).sum())
    return 1.0 if union == 0 else float((a & b).sum() / union)


def _write_history(history: FitHistory, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    history.to_json(path)
    return path


def _accuracy_curve(history: FitHistory, names: Mapping[str, str]) -> tuple[list, dict]:
    """Checkpoint seconds and the metric columns ``{new_name: values}`` of a history."""
    a = history.as_arrays()
    curve = {new: a["metrics"][old].tolist() for old, new in names.items()
             if old in a["metrics"]}
    return a["checkpoint_seconds"].tolist(), curve


def _begin(out, name: str, size: str) -> tuple[StepResult, Path, float]:
    """Check ``size``, start the clock, create ``out/<name>``: the empty result, folder, start."""
    check_choice(size, "size", SIZES)
    t0 = time.perf_counter()
    d = Path(out) / name
    d.mkdir(parents=True, exist_ok=True)
    _, title, tutorial = STEPS[name]
    return StepResult(name, title, tutorial, size=size), d, t0


def _settings_text(settings: Mapping) -> str:
    """``"k=v, k=v"`` of a settings dict (the report's config cells)."""
    return ", ".join(f"{k}={v}" for k, v in settings.items())


def _record_fit(res: StepResult, d: Path, key: str, label: str, fit, metrics: Sequence[str], *,
                final: dict, config: Mapping) -> None:
    """Add one fit's method record (curves of ``metrics`` from its history) and its history."""
    seconds, curve = _accuracy_curve(fit.history, {k: k for k in metrics})
    res.methods.append(_method(key, label, seconds=seconds, curve=curve, final=final,
                               status=fit.status, message=fit.message, config=config))
    res.histories[key] = fit.history
    res.files[f"{key} history"] = _write_history(fit.history, d / f"{key}_history.json")


def _heldout_comparison(res: StepResult, d: Path, targets: np.ndarray, renders: Mapping,
                        fits: Mapping, caption: str) -> None:
    """Save the held-out targets and each method's renders of them, and the comparison panel.

    ``targets`` (k, H, W, 3) are the views shown; ``renders`` map a method to at least k renders
    (k, H, W, 3 or 4) of the same views; ``fits`` map it to its result (``.seconds``).
    """
    k = len(targets)
    res.targets["held-out views"] = save_png(np.concatenate(list(targets), axis=1),
                                             d / "target.png")
    for key, r in renders.items():
        res.images[key] = save_png(np.concatenate(list(r[:k, ..., :3]), axis=1), d / f"{key}.png")
    res.comparison = image_panel(
        [[targets[i]] + [renders[key][i, ..., :3] for key in renders] for i in range(k)],
        d / "comparison.png",
        col_labels=["held-out target"] + [f"{key}\n{fits[key].seconds:.1f} s" for key in fits],
        row_labels=[f"view {i + 1}" for i in range(k)])
    res.comparison_caption = caption


def _run_cases(cases: Mapping[str, Callable[[], Any]]) -> list[dict]:
    """One stability row per case: ``str`` of what it returned, or how it failed."""
    rows = []
    for case, fn in cases.items():  # failure cases
        r, err = _try(fn)
        rows.append({"case": case, "outcome": err if err is not None else str(r)})
    return rows


def _fit_row(method: str, case: str, fit, err: str | None,
             measure: Callable[[Any], dict]) -> dict:
    """A fit's stability row: how it failed, or how it stopped and ``measure(fit)``."""
    row = {"method": method, "case": case}
    if err is not None:
        row["outcome"] = err
    else:
        row.update(outcome="converged" if fit.converged else f"stopped: {fit.status}",
                   **measure(fit))
    return row


# --------------------------------------------------------------------------------------------
# 1. fit a mesh to a mesh
# --------------------------------------------------------------------------------------------

_FIT_MESH_LABELS = {
    "tutorial": "PyTorch3D recipe: SGD lr 1, momentum 0.9, ico4, sampled chamfer",
    "scipy-lbfgs": "geofit: scipy L-BFGS-B, exact distances (ico4)",
    "large-steps": "geofit: large steps + L-BFGS (ico4)",
    "coarse-to-fine": "geofit: coarse-to-fine + large steps + L-BFGS",
}


def _fit_mesh_settings(name: str, size: str) -> dict:
    from .fit import RECIPES, CoarseToFine

    kw = dict(RECIPES[name])
    stochastic = kw["method"] in ("sgd", "adam")
    if size == "full":
        kw["checkpoint_every"] = 100 if stochastic else 10
        return kw
    if stochastic:
        kw.update(n_iter=_pick(size, 20, 300, 2000), checkpoint_every=_pick(size, 10, 50, 100))
        if size == "tiny":
            kw.update(n_samples=500)
    else:
        kw.update(n_iter=_pick(size, 8, 30, 100), n_stages=_pick(size, 1, 2, 3),
                  checkpoint_every=_pick(size, 4, 10, 10))
        if size == "tiny":
            kw.update(n_samples=500)
    if name == "coarse-to-fine":
        kw["coarse_to_fine"] = CoarseToFine(max_level=_pick(size, 2, 4, 4),
                                            start_level=_pick(size, 1, 2, 2))
        kw.pop("n_stages", None)
    elif size == "tiny":
        kw["source"] = 2
    return kw


def _fit_mesh_stability(target, methods, size: str, seed: int, progress: bool) -> list[dict]:
    """Each method on noisy / holed / NaN targets, a degenerate start and a 100x step."""
    from .fit import CoarseToFine, fit_mesh
    from .metrics import MeshEvaluator
    from .shapes import ico_sphere
    from .structures import Mesh

    budget = _pick(size, 0.5, 2.0, 20.0)
    n_metric = _pick(size, 1000, 5000, 20000)
    rng = np.random.default_rng(seed + 7)
    norm = target.normalize()
    tn = norm.mesh
    centres = tn.verts[rng.choice(tn.n_verts, 4, replace=False)]
    d = np.linalg.norm(tn.verts[tn.faces].mean(1)[:, None, :] - centres[None], axis=2).min(1)
    noisy = target.update_verts(target.verts + rng.normal(scale=0.01 * norm.scale,
                                                          size=target.verts.shape))
    nan_v = target.verts.copy()
    nan_v[0, 0] = np.nan
    cases = {
        "noisy target (sigma 1%)": {"target": noisy},
        "target with 4 holes": {"target": Mesh(target.verts, target.faces[d > 0.15])},
        "NaN in the target": {"target": (nan_v, target.faces)},
        "degenerate start (every 7th edge collapsed)": {"degenerate": True},
        "step 100x too large": {"x100": True},
    }
    evaluator = MeshEvaluator(target, n_samples=n_metric, taus=0.01, normalize=True, seed=0)

    def measure(res):
        m = evaluator.evaluate(res.mesh)
        return {"chamfer-L2": m.chamfer_l2, "F@0.01": m.fscore[0.01],
                "NaN vertices": bool(np.isnan(res.mesh.verts).any()),
                "seconds": round(res.seconds, 2)}

    rows = []
    bar = _bar(progress, len(cases) * len(methods), "fit_mesh stability")
    for name in methods:  # methods
        for case, spec in cases.items():  # failure cases
            kw = _fit_mesh_settings(name, size)
            kw.pop("checkpoint_every", None)
            source = kw.pop("source", None)
            if kw["method"] in ("sgd", "adam"):
                kw["n_iter"] = min(kw["n_iter"], _pick(size, 10, 100, 500))
            if spec.get("degenerate"):
                c2f = kw.get("coarse_to_fine")
                level = c2f.start_level if isinstance(c2f, CoarseToFine) else (source or 4)
                src = ico_sphere(level)
                v = src.verts.copy()
                e = src.edges[::7]
                v[e[:, 0]] = v[e[:, 1]]
                source = src.update_verts(v)
            if spec.get("x100"):
                if kw["method"] in ("sgd", "adam"):
                    kw["lr"] = 100.0 * kw.get("lr", 1.0 if kw["method"] == "sgd" else 0.01)
                else:
                    from .fit import FINE_WEIGHTS, TUTORIAL_WEIGHTS

                    x100 = {k: 100 * v for k, v in TUTORIAL_WEIGHTS.items()}
                    kw["weights"] = [x100, {k: 100 * v for k, v in FINE_WEIGHTS.items()}]
                    if isinstance(kw.get("coarse_to_fine"), CoarseToFine):
                        kw["coarse_to_fine"].coarse_weights = x100
            res, err = _try(fit_mesh, source, spec.get("target", target), evaluator=None,
                            progress=False, time_budget=budget, seed=seed, **kw)
            rows.append(_fit_row(name, case, res, err, measure))
            bar.update(1)
    bar.close()
    return rows


def step_fit_mesh(out, size: str = "default", *, progress: bool = True, seed: int = 0
                  ) -> StepResult:
    """Deform an ico-sphere into the target mesh: the tutorial's SGD recipe and geofit's solvers.

    Parameters
    ----------
    out : path
        The run's output folder; the step writes into ``out/fit_mesh``.
    size : {"tiny", "default", "full"}
        ``"full"``: :data:`geofit.fit.RECIPES` as they are (SGD 2000 steps, L-BFGS 3 stages of
        100 iterations); ``"default"``: SGD 300 steps, L-BFGS 2 stages of 30 iterations.
    progress : bool
        tqdm progress bars.
    seed : int
        Sampling seed.

    Returns
    -------
    StepResult
    """
    from .data import load_target_mesh
    from .fit import fit_mesh
    from .metrics import MeshEvaluator

    res, d, t0 = _begin(out, "fit_mesh", size)
    data = load_target_mesh()
    target = data.mesh
    n_metric = _pick(size, 2000, 10_000, 100_000)
    evaluator = MeshEvaluator(target, n_samples=n_metric, taus=0.01, normalize=True, seed=0)
    names = ["tutorial", "scipy-lbfgs", "large-steps", "coarse-to-fine"]
    if size == "tiny":
        names = ["tutorial", "large-steps"]
    res.config = {"target": data.name, "target vertices": target.n_verts,
                  "metric samples a side": n_metric}
    res.description = (
        f"An ico-sphere is deformed into the {data.name} (normalised as in the tutorial). "
        "Accuracy: chamfer-L2 (sum of the two mean squared exact point-to-surface distances) and "
        "F-score at 0.01 in the target's normalised frame (geofit.metrics), on seeded samples. "
        "Times are the solvers' own (the clock is paused while the accuracy is measured).")
    results = {}
    for name in names:  # methods
        kw = _fit_mesh_settings(name, size)
        source = kw.pop("source", None)
        fit = fit_mesh(source, target, evaluator=evaluator, progress=progress, seed=seed, **kw)
        results[name] = fit
        m = fit.metrics
        final = {"seconds": fit.seconds, "n_verts": fit.n_verts, "n_params": fit.n_params,
                 "chamfer_l2": m.chamfer_l2, "fscore@0.01": m.fscore[0.01],
                 "normal_consistency": m.normal_consistency}
        res.files[f"{name} mesh"] = d / f"{name}.obj"
        fit.save_obj(res.files[f"{name} mesh"])
        _record_fit(res, d, name, _FIT_MESH_LABELS[name], fit, ("chamfer_l2", "fscore@0.01"),
                    final=final, config={k: repr(v) if not isinstance(v, (int, float, str))
                                         else v for k, v in kw.items()})
        res.metrics.append({"method": _FIT_MESH_LABELS[name], "status": fit.status,
                            "seconds": round(fit.seconds, 2), "iterations": fit.n_iterations,
                            "chamfer-L2": m.chamfer_l2, "F@0.01": m.fscore[0.01],
                            "normal consistency": m.normal_consistency})
        res.param_counts.append({"method": _FIT_MESH_LABELS[name], "vertices": fit.n_verts,
                                 "free parameters": fit.n_params})
    res.config.update({f"{n} settings": _settings_text(res.methods[i]["config"])
                       for i, n in enumerate(names)})

    # images: the target and every result from two views, in the normalised frame
    norm = target.normalize()
    cams = _cameras(2.1, [15.0, 15.0], [40.0, 140.0])
    img_size = _pick(size, 96, 256, 256)
    shots = {"target": _shade_mesh(norm.mesh, cams, img_size)}
    for name, fit in results.items():
        verts = (fit.mesh.verts - norm.center) / norm.scale  # the target's normalised frame
        shots[name] = _shade_mesh(fit.mesh.update_verts(verts), cams, img_size)
    for k, imgs in shots.items():
        dest = res.targets if k == "target" else res.images
        dest[k] = save_png(np.concatenate(list(imgs), axis=1), d / f"{k}.png")
    cols = ["target"] + [f"{n}\n{results[n].n_verts} verts, {results[n].seconds:.1f} s"
                         for n in results]
    res.comparison = image_panel([[shots[k][v] for k in shots] for v in range(2)],
                                 d / "comparison.png", col_labels=cols,
                                 row_labels=["view 1", "view 2"])
    res.comparison_caption = (f"Target ({data.name}) and the fitted meshes, two views; solver "
                              "seconds and vertex counts above each column.")
    best = min(results, key=lambda n: results[n].metrics.chamfer_l2)
    pt = results["tutorial"]
    res.charts["Speed and accuracy: chamfer-L2 and F-score against solver time"] = \
        plot_accuracy_vs_time(
            _series(res.methods),
            [{"metric": "chamfer_l2", "label": "chamfer-L2 (normalised frame, log)",
              "logy": True, "target": pt.metrics.chamfer_l2,
              "target_label": "PyTorch3D recipe's final accuracy"},
             {"metric": "fscore@0.01", "label": "F-score @ 0.01", "logy": False,
              "target": pt.metrics.fscore[0.01]}],
            d / "speed_accuracy.png",
            title=f"fit_mesh on the {data.name} ({size} size)")
    res.stability = _fit_mesh_stability(target, ["tutorial", "large-steps"], size, seed,
                                        progress)
    res.headline = {
        _P3D: f"chamfer-L2 {pt.metrics.chamfer_l2:.3g}, F {pt.metrics.fscore[0.01]:.3f} in "
              f"{pt.seconds:.1f} s, {pt.n_params:,} params",
        _GF: f"{best}: chamfer-L2 {results[best].metrics.chamfer_l2:.3g}, "
             f"F {results[best].metrics.fscore[0.01]:.3f} in "
             f"{results[best].seconds:.1f} s, {results[best].n_params:,} params",
    }
    if data.path is None:
        res.notes.append("The tutorial's dolphin was not found (set GEOFIT_DATA): the target is "
                         "geofit's procedural stand-in.")
    res.seconds = time.perf_counter() - t0
    return res


# --------------------------------------------------------------------------------------------
# 2. render textured meshes
# --------------------------------------------------------------------------------------------


def _render_stability(mesh, size: str) -> list[dict]:
    """The mesh renderer on awkward input: where does it break, and how."""
    from .render import (
        MeshRasterizer,
        MeshRenderer,
        PointLights,
        RasterizationSettings,
        SoftPhongShader,
    )
    from .structures import Mesh

    s = _pick(size, 32, 128, 256)

    def render(m, cams, **settings):
        r = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=s, **settings)),
                         SoftPhongShader(lights=PointLights(location=[[0.0, 0.0, -3.0]])))
        img = r(m)
        return (f"ok: {100 * float((img[..., 3] > 0).mean()):.1f}% covered, "
                f"finite={bool(np.isfinite(img).all())}")

    front = _cameras(2.7, 0.0, 180.0)
    v = mesh.verts.copy()
    e = mesh.edges[::5]
    v[e[:, 0]] = v[e[:, 1]]
    nan_v = mesh.verts.copy()
    nan_v[0] = np.nan
    cases = {
        "camera inside the mesh (dist 0.3)": lambda: render(mesh, _cameras(0.3, 0.0, 180.0)),
        "mesh behind the camera": lambda: render(
            mesh.update_verts(mesh.verts + np.array([0.0, 0.0, -6.0])), front),
        "every 5th edge collapsed (zero-area faces)": lambda: render(mesh.update_verts(v), front),
        "camera at the pole (elev 90)": lambda: render(mesh, _cameras(2.7, 90.0, 180.0)),
        "1 x 1 image": lambda: "ok: image shape " + str(MeshRenderer(
            MeshRasterizer(front, RasterizationSettings(image_size=1)),
            SoftPhongShader())(mesh).shape),
        "NaN vertex": lambda: render(Mesh(nan_v, mesh.faces, mesh.textures), front),
        "blur_radius > 0 (soft rasterization)": lambda: render(mesh, front, blur_radius=1e-4),
    }
    return _run_cases(cases)


def step_render_mesh(out, size: str = "default", *, progress: bool = True, seed: int = 0
                     ) -> StepResult:
    """Render the textured mesh as the tutorial does; antialiasing cost against accuracy.

    Parameters
    ----------
    out : path
        The run's output folder; the step writes into ``out/render_mesh``.
    size : {"tiny", "default", "full"}
        Image size of the tutorial's views (64 / 512 / 512) and of the batch of views
        (64 / 256 / 512 with 4 / 20 / 20 views).
    progress : bool
        A progress bar over the renders.
    seed : int
        Unused (rendering is deterministic); kept for a common signature.

    Returns
    -------
    StepResult
    """
    from .data import load_textured_mesh
    from .render import (
        Materials,
        MeshRasterizer,
        MeshRenderer,
        PointLights,
        RasterizationSettings,
        SoftPhongShader,
        make_grid,
    )

    res, d, t0 = _begin(out, "render_mesh", size)
    data = load_textured_mesh()
    mesh = data.mesh.normalize().mesh
    S = _pick(size, 64, 512, 512)
    SB = _pick(size, 64, 256, 512)
    NB = _pick(size, 4, 20, 20)
    res.config = {"mesh": data.name, "faces": mesh.n_faces, "image size": S,
                  "batch": f"{NB} views at {SB} px"}
    res.description = (
        "The tutorial's renders by Embree ray casting (one ray per pixel centre: PyTorch3D's "
        "hard rasterization with faces_per_pixel=1): the front view with the light in front, "
        "then behind; a second view with green specular highlights; a batch of views. The "
        "speed-accuracy chart measures antialiasing (rays per pixel) against the error to a "
        "6 x 6 supersampled reference render of the same view.")
    bar = _bar(progress, 5, "render_mesh")
    front = _cameras(2.7, 0.0, 180.0)

    def renderer(cams, size_, lights, **settings):
        return MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=size_,
                                                                       **settings)),
                            SoftPhongShader(lights=lights))

    timings = {}
    t = time.perf_counter()
    img1 = renderer(front, S, PointLights(location=[[0.0, 0.0, -3.0]]))(mesh)
    timings["front view"] = time.perf_counter() - t
    bar.update(1)
    img2 = renderer(front, S, PointLights(location=[[0.0, 0.0, 1.0]]))(mesh)
    bar.update(1)
    t = time.perf_counter()
    img3 = renderer(_cameras(2.7, 10.0, -150.0), S, PointLights(location=[[2.0, 2.0, -2.0]]))(
        mesh, materials=Materials(specular_color=[[0.0, 1.0, 0.0]], shininess=10.0))
    timings["second view, green specular"] = time.perf_counter() - t
    bar.update(1)
    cams_b = _cameras(2.7, np.linspace(0.0, 180.0, NB), np.linspace(-180.0, 180.0, NB))
    t = time.perf_counter()
    batch = renderer(cams_b, SB, PointLights(location=[[0.0, 0.0, -3.0]]))(mesh.extend(NB))
    timings[f"batch of {NB} views"] = time.perf_counter() - t
    bar.update(1)

    res.images["front view, light in front"] = save_png(img1[0, ..., :3], d / "front.png")
    res.images["front view, light behind"] = save_png(img2[0, ..., :3], d / "light_behind.png")
    res.images["second view, green specular"] = save_png(img3[0, ..., :3], d / "specular.png")
    res.images["batch of views"] = save_png(make_grid(batch, cols=min(NB, 5)), d / "batch.png")
    tex = getattr(mesh.textures, "maps", None)
    if tex is not None:
        tex = np.asarray(tex)
        res.targets["texture map (input)"] = save_png(tex[..., :3], d / "texture.png")

    # antialiasing: rays per pixel side against the error to a supersampled reference
    lights = PointLights(location=[[0.0, 0.0, -3.0]])
    sizes = _pick(size, (32, 64), (128, 256, 512), (128, 256, 512))
    factors = _pick(size, (1, 2), (1, 2, 3), (1, 2, 3, 4))
    ref_factor = _pick(size, 3, 6, 8)
    methods = []
    reference = None
    for s_ in sizes:  # image sizes
        ref = renderer(front, s_, lights, supersample=ref_factor)(mesh)[0, ..., :3]
        if s_ == sizes[-1]:
            reference = ref
        secs, err = [], []
        for f in factors:  # supersampling factors
            r = renderer(front, s_, lights, supersample=f)
            t = time.perf_counter()
            img = r(mesh)[0, ..., :3]
            secs.append(time.perf_counter() - t)
            err.append(float(np.abs(img - ref).mean()))
        methods.append(_method(f"{s_}px", f"{s_} x {s_}, 1..{factors[-1]} rays per pixel side",
                               seconds=secs, curve={"mean_abs_error": err},
                               final={"rays_per_pixel_side": list(factors), "seconds": secs,
                                      "mean_abs_error": err}, status="ok"))
        res.metrics += [{"image": f"{s_} x {s_}", "rays per pixel": f * f,
                         "seconds": round(secs[i], 4), "mean |RGB - reference|": err[i]}
                        for i, f in enumerate(factors)]
    bar.update(1)
    bar.close()
    res.methods = methods
    res.metrics += [{"image": k, "seconds": round(v, 4)} for k, v in timings.items()]
    res.targets[f"reference ({ref_factor}x{ref_factor} rays per pixel)"] = save_png(
        reference, d / "reference.png")
    res.comparison = image_panel(
        [[reference, img1[0], img2[0], img3[0]]], d / "comparison.png",
        col_labels=[f"reference\n{ref_factor}x{ref_factor} rays/pixel",
                    "1 ray/pixel\n(PyTorch3D's)", "light behind", "second view\ngreen specular"])
    res.comparison_caption = ("The supersampled reference next to the tutorial's renders "
                              f"({data.name}).")
    res.charts["Speed and accuracy: antialiasing cost against the error to the reference"] = \
        plot_accuracy_vs_time(_series(methods), [
            {"metric": "mean_abs_error", "label": "mean |RGB - reference| (log)", "logy": True}],
            d / "speed_accuracy.png", xlabel="render wall time (s, log)",
            title=f"render_mesh: rays per pixel against error ({data.name}, {size} size)")
    tex_px = 0 if tex is None else int(tex.shape[0] * tex.shape[1])
    res.param_counts = [{"model": "scene: vertices", "count": mesh.n_verts},
                        {"model": "scene: faces", "count": mesh.n_faces},
                        {"model": "scene: texture texels", "count": tex_px}]
    res.stability = _render_stability(mesh, size)
    res.headline = {_P3D: f"{S} x {S}, 1 ray/pixel: {timings['front view']:.3f} s per view",
                    _GF: f"batch of {NB} at {SB} px in "
                         f"{timings[f'batch of {NB} views']:.2f} s"}
    if data.path is None:
        res.notes.append("The tutorial's cow was not found (set GEOFIT_DATA): the mesh is "
                         "geofit's procedural textured stand-in.")
    res.seconds = time.perf_counter() - t0
    return res


# --------------------------------------------------------------------------------------------
# 3. render coloured point clouds
# --------------------------------------------------------------------------------------------


#: The point-cloud tutorial's own cloud, relative to the data folder (:func:`geofit.data.find`).
_BRIDGE = "PittsburghBridge/pointcloud.npz"


def _points_stability(cloud, cameras, size: str) -> list[dict]:
    from .render.points.compositing import AlphaCompositor
    from .render.points import PointsRasterizationSettings, PointsRasterizer, PointsRenderer
    from .structures import PointCloud

    s = _pick(size, 32, 128, 256)

    def render(c, cams=cameras, radius=0.003, K=10):
        out = PointsRenderer(PointsRasterizer(cams, PointsRasterizationSettings(
            image_size=s, radius=radius, points_per_pixel=K)), AlphaCompositor()).render(c)
        return (f"ok: {100 * float(out.fragments.mask.mean()):.1f}% covered, "
                f"finite={bool(np.isfinite(out.images).all())}")

    P, C = cloud.points, cloud.features
    nan_p = P.copy()
    nan_p[0] = np.nan
    cases = {
        "NaN point": lambda: render(PointCloud(nan_p, C)),
        "empty cloud": lambda: render(PointCloud(np.zeros((0, 3)), np.zeros((0, 3)))),
        "all points behind the camera": lambda: render(
            PointCloud(P + np.array([0.0, 0.0, 50.0]), C), _cameras(2.7, 0.0, 0.0)),
        "all points at one place": lambda: render(PointCloud(np.zeros_like(P), C)),
        "radius 0": lambda: render(cloud, radius=0.0),
        "radius 0.5 (huge splats)": lambda: render(cloud, radius=0.5, K=2),
        "points_per_pixel 0": lambda: render(cloud, K=0),
    }
    return _run_cases(cases)


def step_render_points(out, size: str = "default", *, progress: bool = True, seed: int = 0
                       ) -> StepResult:
    """Render a coloured point cloud as the tutorial does; point count and radius against accuracy.

    The cloud is sampled from the textured mesh with its texture colours, so the mesh's own
    (unlit) render from the same camera is the target the point renders should reproduce.

    Parameters
    ----------
    out : path
        The run's output folder; the step writes into ``out/render_points``.
    size : {"tiny", "default", "full"}
        Cloud of 5 000 / 100 000 / 500 000 points, images of 64 / 256 / 512 pixels.
    progress : bool
        A progress bar over the renders.
    seed : int
        Sampling seed.

    Returns
    -------
    StepResult
    """
    from .data import find, load_textured_mesh
    from .io import load_pointcloud
    from .ops import sample_points_from_meshes
    from .render import (
        AmbientLights,
        BlendParams,
        HardPhongShader,
        MeshRasterizer,
        MeshRenderer,
        RasterizationSettings,
    )
    from .render.points.compositing import AlphaCompositor, NormWeightedCompositor
    from .render.points import PointsRasterizationSettings, PointsRasterizer, PointsRenderer
    from .structures import PointCloud

    res, d, t0 = _begin(out, "render_points", size)
    data = load_textured_mesh()
    mesh = data.mesh.normalize().mesh
    N = _pick(size, 5_000, 100_000, 500_000)
    S = _pick(size, 64, 256, 512)
    res.config = {"cloud": f"{N} samples of the {data.name} with texture colours",
                  "image size": S, "radius (NDC)": 0.003, "points per pixel": 10,
                  "camera": "FoVOrthographicCameras(znear=0.01), look_at(20, 10, 180)"}
    res.description = (
        "The tutorial's three renders of a coloured cloud (alpha compositing, the same on a "
        "blue background, normalised weighted sum on red), from its orthographic camera. The "
        "cloud samples the textured mesh, so the mesh's unlit render from the same camera is "
        "the target: the chart measures how the point count and radius trade render time "
        "against coverage (silhouette IoU) and colour error.")
    cams = _cameras(20.0, 10.0, 180.0, ortho=True, znear=0.01)
    bar = _bar(progress, 4, "render_points")
    sample = sample_points_from_meshes(mesh, N, seed=seed, return_textures=True)
    cloud = PointCloud(sample.points, sample.textures[:, :3])
    settings = PointsRasterizationSettings(image_size=S, radius=0.003, points_per_pixel=10)
    rast = PointsRasterizer(cams, settings)
    timings = {}
    imgs = {}
    for key, comp in (("alpha", AlphaCompositor()),
                      ("alpha, blue background", AlphaCompositor(background_color=(0, 0, 1))),
                      ("normalised weighted, red background",
                       NormWeightedCompositor(background_color=(1, 0, 0)))):
        r = PointsRenderer(rast, comp)
        t = time.perf_counter()
        imgs[key] = r(cloud)[0, ..., :3]
        timings[key] = time.perf_counter() - t
    bar.update(1)
    target = MeshRenderer(
        MeshRasterizer(cams, RasterizationSettings(image_size=S)),
        HardPhongShader(lights=AmbientLights(), blend_params=BlendParams(
            background_color=(0.0, 0.0, 0.0))))(mesh)[0]
    target_rgb, target_mask = target[..., :3].astype(np.float64), target[..., 3] > 0
    bar.update(1)
    for i, (k, v) in enumerate(imgs.items()):
        res.images[k] = save_png(v, d / f"points_{i}.png")
    res.targets["mesh, unlit (target)"] = save_png(target_rgb, d / "target_mesh.png")
    rows = [[target_rgb] + list(imgs.values())]
    row_labels = [f"{data.name}\n{N:,} points"]
    bridge_path = find(_BRIDGE)
    if bridge_path is not None:  # the tutorial's own cloud and camera, when it is available
        bridge = load_pointcloud(bridge_path)
        bcams = _cameras(20.0, 10.0, 0.0, ortho=True, znear=0.01)
        brast = PointsRasterizer(bcams, settings)
        row = [None]
        for i, comp in enumerate((AlphaCompositor(), AlphaCompositor(background_color=(0, 0, 1)),
                                  NormWeightedCompositor(background_color=(1, 0, 0)))):
            t = time.perf_counter()
            img_b = PointsRenderer(brast, comp)(bridge)[0, ..., :3]
            timings[f"PittsburghBridge ({len(bridge):,} points), render {i + 1}"] = \
                time.perf_counter() - t
            res.images[f"PittsburghBridge render {i + 1}"] = save_png(img_b,
                                                                      d / f"bridge_{i}.png")
            row.append(img_b)
        rows.append(row)
        row_labels.append(f"PittsburghBridge\n{len(bridge):,} points")
        res.notes.append(f"The tutorial's PittsburghBridge cloud was found ({bridge_path}) and "
                         "rendered with the tutorial's camera (second row).")
    res.comparison = image_panel(rows, d / "comparison.png",
                                 col_labels=["target: the mesh\n(unlit texture)", "alpha",
                                             "alpha\nblue background",
                                             "norm. weighted\nred background"],
                                 row_labels=row_labels)
    res.comparison_caption = (f"The mesh the cloud was sampled from, and the tutorial's three "
                              f"point renders (radius 0.003, {S} px).")

    counts = _pick(size, (1_000, 5_000), (12_500, 25_000, 50_000, 100_000, 200_000),
                   (50_000, 100_000, 200_000, 500_000, 1_000_000))
    radii = (0.003, 0.006) if size != "tiny" else (0.01, 0.02)
    big = sample_points_from_meshes(mesh, counts[-1], seed=seed + 1, return_textures=True)
    methods = []
    for radius in radii:  # radii
        secs, iou, err = [], [], []
        r = PointsRenderer(PointsRasterizer(cams, PointsRasterizationSettings(
            image_size=S, radius=radius, points_per_pixel=10)), AlphaCompositor())
        for n in counts:  # cloud sizes
            c = PointCloud(big.points[:n], big.textures[:n, :3])
            t = time.perf_counter()
            o = r.render(c)
            secs.append(time.perf_counter() - t)
            iou.append(_iou(o.fragments.mask[0], target_mask))
            err.append(float(np.abs(o.images[0, ..., :3] - target_rgb).mean()))
        methods.append(_method(f"r{radius:g}", f"radius {radius:g}, {counts[0]:,}..{counts[-1]:,}"
                               " points", seconds=secs, curve={"iou": iou, "mean_abs_error": err},
                               final={"points": list(counts)}, status="ok"))
        res.metrics += [{"points": n, "radius": radius, "seconds": round(secs[i], 4),
                         "silhouette IoU vs mesh": iou[i], "mean |RGB - mesh|": err[i]}
                        for i, n in enumerate(counts)]
    bar.update(1)
    res.methods = methods
    res.metrics += [{"points": N, "radius": 0.003, "render": k, "seconds": round(v, 4)}
                    for k, v in timings.items()]
    res.charts["Speed and accuracy: point count and radius against coverage and colour "
               "error"] = plot_accuracy_vs_time(
        _series(methods),
        [{"metric": "iou", "label": "silhouette IoU against the mesh"},
         {"metric": "mean_abs_error", "label": "mean |RGB - mesh render| (log)", "logy": True}],
        d / "speed_accuracy.png", xlabel="render wall time (s, log)",
        title=f"render_points: {data.name} samples, {S} px ({size} size)")
    res.param_counts = [{"model": "cloud: points", "count": N},
                        {"model": "cloud: colour values", "count": 3 * N}]
    res.stability = _points_stability(cloud, cams, size)
    bar.update(1)
    bar.close()
    res.headline = {_P3D: f"{N:,} points at {S} px, K=10: {timings['alpha']:.3f} s",
                    _GF: f"{counts[-1]:,} points, radius {radii[-1]:g}: IoU "
                         f"{methods[-1]['curve']['iou'][-1]:.3f} vs the mesh in "
                         f"{methods[-1]['curve']['seconds'][-1]:.3f} s"}
    res.notes.append(f"The measured cloud is sampled from the {data.name} with its texture "
                     "colours, so the mesh's own render is a target to compare with"
                     + ("." if bridge_path is not None else
                        f"; the tutorial's {_BRIDGE} was not found in the data folder "
                        "(GEOFIT_DATA)."))
    res.seconds = time.perf_counter() - t0
    return res


# --------------------------------------------------------------------------------------------
# Shared by 5 and 6: the tutorials' renders of the cow (black background, silhouettes)
# --------------------------------------------------------------------------------------------


def _cow_views(n_views: int, image_size: int, n_heldout: int, heldout_size: int):
    """Training and held-out renders of the volume and NeRF tutorials (:mod:`geofit.datasets`).

    Training: ``generate_cow_renders`` (elevation 0, azimuths around the cow, black background,
    0/1 silhouettes). Held out: views half-way between the training azimuths, at elevations 0
    and 20 degrees (20 only when a single view is asked for).
    """
    from .datasets import generate_cow_renders, held_out_views

    train = generate_cow_renders(num_views=n_views, image_size=image_size)
    elevations = (0.0, 20.0) if n_heldout >= 2 else (20.0,)
    test = held_out_views(num_views=n_views, elevations=elevations,
                          n_azimuths=max(1, n_heldout // len(elevations)),
                          image_size=heldout_size)
    return train, test, train.mesh_name


def _render_volume(volume, cameras, image_size: int, n_pts: int) -> np.ndarray:
    from .render.volume.raymarching import EmissionAbsorptionRaymarcher
    from .render.volume.raysampling import NDCMultinomialRaysampler
    from .render.volume import VolumeRenderer

    r = VolumeRenderer(NDCMultinomialRaysampler(image_width=image_size, image_height=image_size,
                                                n_pts_per_ray=n_pts, min_depth=0.1,
                                                max_depth=3.0),
                       EmissionAbsorptionRaymarcher())
    return r(cameras, volume)[0]


# --------------------------------------------------------------------------------------------
# 4. fit a mesh to multi-view images
# --------------------------------------------------------------------------------------------


def _views_settings(size: str) -> dict:
    return {
        "num_views": _pick(size, 4, 20, 20),
        "image_size": _pick(size, 32, 64, 128),
        "num_heldout": _pick(size, 2, 8, 16),
        # PyTorch3D's recipe (fit_textured_mesh): SGD on 2 random views, then the textured
        # stage from the sphere
        "tutorial": {"silhouette_method": "tutorial", "textured_method": "tutorial",
                     "textured_init": "sphere",
                     "silhouette_iters": _pick(size, 4, 150, 2000),
                     "textured_iters": _pick(size, 4, 150, 2000)},
        # geofit's best (benchmarks/fit_views.py "best"): L-BFGS on all views, large steps,
        # coarse-to-fine; least-squares colours, then joint L-BFGS
        "geofit": {"silhouette_method": "scipy-lbfgs", "textured_method": "lbfgs",
                   "large_steps": 10.0,
                   "levels": _pick(size, None, [(0, 2), (1, 1)], [(0, 2), (1, 1)]),
                   "silhouette_iters": _pick(size, 4, 60, 2000),
                   "textured_iters": _pick(size, 4, 30, 200),
                   "textured_time": _pick(size, None, 10.0, 120.0)},
        "init_level": _pick(size, 2, 4, 4),
        "eval_every": _pick(size, 1e9, 4.0, 20.0),
    }


def step_fit_views(out, size: str = "default", *, progress: bool = True, seed: int = 0
                   ) -> StepResult:
    """Fit a mesh and vertex colours to multi-view images: the tutorial's SGD and geofit's solvers.

    Parameters
    ----------
    out : path
        The run's output folder; the step writes into ``out/fit_views``.
    size : {"tiny", "default", "full"}
        ``"full"``: 20 views of 128 px, 2000 SGD steps per stage as the tutorial;
        ``"default"``: 20 views of 64 px, 150 SGD steps per stage.
    progress : bool
        A progress bar over the stages.
    seed : int
        Random view choices of the SGD recipe.

    Returns
    -------
    StepResult
    """
    from .fit.views import ViewsEvaluator, cow_multiview_dataset, fit_mesh_to_views
    from .io import save_obj
    from .render import MeshRasterizer, MeshRenderer, RasterizationSettings, SoftPhongShader
    from .shapes import ico_sphere
    from .structures import Mesh, TexturesVertex

    res, d, t0 = _begin(out, "fit_views", size)
    cfg = _views_settings(size)
    ds = cow_multiview_dataset(num_views=cfg["num_views"], image_size=cfg["image_size"],
                               num_heldout=cfg["num_heldout"])
    res.config = {"object": ds.name, "training views": cfg["num_views"],
                  "held-out views": cfg["num_heldout"], "image size": cfg["image_size"],
                  "PyTorch3D recipe": _settings_text(cfg["tutorial"]),
                  "geofit": _settings_text(cfg["geofit"])}
    res.description = (
        "A sphere is deformed to match the soft silhouettes of the training views, then its "
        "vertex colours (and positions) are fitted to the RGB images. Accuracy on held-out "
        "views: silhouette IoU and RGB PSNR (hard renders), and chamfer-L2 / F-score at 0.01 "
        "against the true mesh. Times are solver times (the clock is paused at checkpoints).")
    ev = ViewsEvaluator(ds.heldout, ds.mesh, n_samples=_pick(size, 2000, 10_000, 20_000),
                        taus=(0.01,))
    labels = {"tutorial": "PyTorch3D recipe: SGD, 2 random views per step",
              "geofit": "geofit: L-BFGS on all views, large steps, coarse-to-fine; "
                        "least-squares then L-BFGS colours"}

    def evaluate(mesh, colors):
        # the silhouette stage has no colours yet: score its shape in a uniform grey, so that
        # every checkpoint has the same metrics (PSNR then rises in the textured stage)
        if colors is None:
            colors = np.full((mesh.n_verts, 3), 0.5)
        return ev(mesh, colors)

    bar = _bar(progress, len(labels), "fit_views")
    fits = {}
    for name, label in labels.items():  # methods
        kw = dict(cfg[name])
        init = ico_sphere(cfg["init_level"] - (1 if kw.get("levels") else 0))
        fit = fit_mesh_to_views(ds.train, init=init, evaluate=evaluate,
                                eval_every=cfg["eval_every"], seed=seed, **kw)
        fits[name] = fit
        final = ev(fit.mesh, fit.colors)
        n_colors = 0 if fit.colors is None else int(np.size(fit.colors))
        res.files[f"{name} mesh"] = d / f"{name}.obj"
        save_obj(res.files[f"{name} mesh"], fit.mesh)
        _record_fit(res, d, name, label, fit, ("iou", "chamfer_l2", "psnr"),
                    final={"seconds": fit.seconds, **final,
                           "n_params": 3 * fit.mesh.n_verts + n_colors}, config=kw)
        res.metrics.append({"method": label, "status": fit.status,
                            "seconds": round(fit.seconds, 2), **final})
        res.param_counts.append({"method": label, "vertices": fit.mesh.n_verts,
                                 "position parameters": 3 * fit.mesh.n_verts,
                                 "colour parameters": n_colors,
                                 "free parameters": 3 * fit.mesh.n_verts + n_colors})
        bar.update(1)
    bar.close()

    # held-out renders of each result next to the held-out targets
    h = ds.heldout
    k = min(3, len(h))
    cams = h.cameras[np.arange(k)]
    ras = MeshRasterizer(cams, RasterizationSettings(image_size=h.image_size))
    renders = {}
    for name, fit in fits.items():
        colors = fit.colors if fit.colors is not None else np.full((fit.mesh.n_verts, 3), 0.7)
        m = Mesh(fit.mesh.verts, fit.mesh.faces, TexturesVertex(np.clip(colors, 0.0, 1.0)))
        renders[name] = np.asarray(MeshRenderer(ras, SoftPhongShader(cameras=cams,
                                                                     lights=h.lights))(
            m.extend(k))[..., :3], dtype=np.float64)
    _heldout_comparison(res, d, h.images[:k], renders, fits,
                        f"Held-out views of the {ds.name} (never trained on) and the fitted "
                        "meshes rendered from them.")
    panels = [{"metric": "iou", "label": "held-out silhouette IoU"}]
    if any("chamfer_l2" in m["curve"] for m in res.methods):
        panels.append({"metric": "chamfer_l2", "label": "chamfer-L2 vs true mesh (log)",
                       "logy": True})
    res.charts["Speed and accuracy: held-out IoU and chamfer-L2 against solver time"] = \
        plot_accuracy_vs_time(_series(res.methods), panels, d / "speed_accuracy.png",
                              title=f"fit_mesh_to_views on the {ds.name} ({size} size)")
    res.stability = _views_stability(ds, size, seed)
    pt, gf = res.metrics[0], res.metrics[1]
    res.headline = {
        _P3D: f"IoU {pt.get('iou', float('nan')):.3f}, PSNR "
              f"{pt.get('psnr', float('nan')):.1f} dB in {pt['seconds']:.1f} s",
        _GF: f"IoU {gf.get('iou', float('nan')):.3f}, PSNR "
             f"{gf.get('psnr', float('nan')):.1f} dB in {gf['seconds']:.1f} s"}
    res.seconds = time.perf_counter() - t0
    return res


def _views_stability(ds, size: str, seed: int) -> list[dict]:
    from .fit.views import MultiViewData, fit_mesh_to_views
    from .shapes import ico_sphere

    tr = ds.train
    iters = _pick(size, 2, 10, 40)
    nan_sil = tr.silhouettes.copy()
    nan_sil[0, 0, 0] = np.nan
    rng = np.random.default_rng(seed + 3)
    cases = {
        "one view only": lambda: MultiViewData(tr.cameras[[0]], tr.silhouettes[:1],
                                               tr.images[:1], tr.lights),
        "empty silhouettes": lambda: MultiViewData(tr.cameras, np.zeros_like(tr.silhouettes),
                                                   tr.images, tr.lights),
        "noisy silhouettes (20% pixels flipped)": lambda: MultiViewData(
            tr.cameras, np.where(rng.random(tr.silhouettes.shape) < 0.2,
                                 1.0 - tr.silhouettes, tr.silhouettes), tr.images, tr.lights),
        "NaN in a silhouette": lambda: MultiViewData(tr.cameras, nan_sil, tr.images, tr.lights),
    }
    rows = []
    for method, kw in (("tutorial", {"silhouette_method": "tutorial",
                                     "textured_method": "none"}),
                       ("geofit", {"silhouette_method": "scipy-lbfgs", "textured_method": "none",
                                   "large_steps": 10.0})):
        for case, make in cases.items():  # failure cases
            def run(make=make, kw=kw):
                views = make()
                vps = min(2, len(views))
                return fit_mesh_to_views(views, init=ico_sphere(2), silhouette_iters=iters,
                                         views_per_step=vps, seed=seed, **kw)
            fit, err = _try(run)
            rows.append(_fit_row(method, case, fit, err, lambda f: {
                "NaN vertices": bool(np.isnan(f.mesh.verts).any()),
                "seconds": round(f.seconds, 2)}))
    return rows


# --------------------------------------------------------------------------------------------
# 5. fit a voxel volume
# --------------------------------------------------------------------------------------------


def _volume_settings(size: str) -> dict:
    budget = _pick(size, None, 30.0, None)
    return {
        "n_views": _pick(size, 6, 20, 40), "image_size": _pick(size, 32, 64, 128),
        "n_heldout": _pick(size, 2, 4, 8), "volume_size": _pick(size, 16, 64, 128),
        "n_pts_per_ray": _pick(size, 32, 75, 150),
        "tutorial": {"method": "tutorial", "n_iter": _pick(size, 4, 300, 300),
                     "batch_size": _pick(size, 2, 10, 10), "time_budget": budget},
        "lbfgs": {"method": "lbfgs", "levels": _pick(size, (8, 16), (32, 64), (32, 64, 128)),
                  "iterations": _pick(size, (4, 4), (60, 40), None), "time_budget": budget},
        "monitor_every": _pick(size, None, 3.0, 30.0),
    }


def step_fit_volume(out, size: str = "default", *, progress: bool = True, seed: int = 0
                    ) -> StepResult:
    """Fit a voxel volume to posed renders: the tutorial's dense Adam and geofit's sparse L-BFGS.

    Parameters
    ----------
    out : path
        The run's output folder; the step writes into ``out/fit_volume``.
    size : {"tiny", "default", "full"}
        ``"full"``: 40 views of 128 px, a 128^3 grid, 150 samples per ray, 300 Adam steps as
        the tutorial; ``"default"``: 20 views of 64 px, 64^3, 75 samples, each method stopped
        after 30 s of solver time.
    progress : bool
        A progress bar over the fits.
    seed : int
        The tutorial recipe's random view batches.

    Returns
    -------
    StepResult
    """
    from .fit.volume import fit_volume

    res, d, t0 = _begin(out, "fit_volume", size)
    cfg = _volume_settings(size)
    S, n_pts, img = cfg["volume_size"], cfg["n_pts_per_ray"], cfg["image_size"]
    train, test, name = _cow_views(cfg["n_views"], img, cfg["n_heldout"], img)
    res.config = {"object": name, "training views": cfg["n_views"],
                  "held-out views": cfg["n_heldout"], "image size": img,
                  "grid": f"{S}^3", "samples per ray": n_pts,
                  "PyTorch3D recipe": _settings_text(cfg["tutorial"]),
                  "geofit": _settings_text(cfg["lbfgs"])}
    res.description = (
        "A grid of densities and colours is fitted to the renders (black background) with "
        "the emission-absorption raymarcher. Accuracy: PSNR of the RGB and IoU of the "
        "silhouette on held-out views (azimuths half-way between the training views, elevations "
        "0 and 20 degrees). "
        "Model size: the densities and colours the solver optimises.")
    labels = {"tutorial": "PyTorch3D recipe: dense grid, Adam, 10 random views per step",
              "lbfgs": "geofit: visual hull, coarse-to-fine, pruning, L-BFGS on all rays"}

    def monitor(volume):
        out_ = _render_volume(volume, test.cameras, img, n_pts)
        return {"psnr": _psnr(out_[..., :3], test.images),
                "iou": float(np.mean([_iou(out_[i, ..., 3], test.silhouettes[i])
                                      for i in range(len(test.images))]))}

    bar = _bar(progress, len(labels), "fit_volume")
    fits, renders = {}, {}
    for key, label in labels.items():  # methods
        kw = dict(cfg[key])
        fit = fit_volume(train.images, train.silhouettes, train.cameras, volume_size=S,
                         n_pts_per_ray=n_pts, seed=seed, monitor=monitor,
                         monitor_every=cfg["monitor_every"], **kw)
        fits[key] = fit
        renders[key] = _render_volume(fit.volume, test.cameras, img, n_pts)
        final = monitor(fit.volume)
        _record_fit(res, d, key, label, fit, ("psnr", "iou"),
                    final={"seconds": fit.seconds, **final, "n_params": fit.n_params},
                    config={k: repr(v) for k, v in kw.items()})
        vol = fit.volume
        np.savez_compressed(d / f"{key}_volume.npz", densities=vol.densities,
                            features=vol.features, voxel_size=vol.voxel_size,
                            volume_translation=vol.volume_translation)
        res.files[f"{key} volume"] = d / f"{key}_volume.npz"
        res.metrics.append({"method": label, "status": fit.status,
                            "seconds": round(fit.seconds, 2), "held-out PSNR (dB)": final["psnr"],
                            "held-out IoU": final["iou"],
                            "samples per ray": round(fit.samples_per_ray, 1)})
        res.param_counts.append({"method": label, "grid": f"{S}^3",
                                 "dense grid values": 4 * S ** 3,
                                 "optimised densities": fit.n_active_voxels,
                                 "optimised colours": 3 * fit.n_colour_voxels,
                                 "free parameters": fit.n_params})
        bar.update(1)
    bar.close()
    _heldout_comparison(res, d, test.images[:3], renders, fits,
                        f"Held-out views of the {name} and the fitted volumes rendered from them.")
    res.charts["Speed and accuracy: held-out PSNR and IoU against solver time"] = \
        plot_accuracy_vs_time(_series(res.methods),
                              [{"metric": "psnr", "label": "held-out PSNR (dB)"},
                               {"metric": "iou", "label": "held-out silhouette IoU"}],
                              d / "speed_accuracy.png",
                              title=f"fit_volume on the {name} ({size} size)")
    res.stability = _volume_stability(train, S, n_pts, size, seed)
    pt, gf = res.metrics
    res.headline = {
        _P3D: f"PSNR {pt['held-out PSNR (dB)']:.1f} dB in {pt['seconds']:.1f} s, "
              f"{res.param_counts[0]['free parameters']:,} params",
        _GF: f"PSNR {gf['held-out PSNR (dB)']:.1f} dB in {gf['seconds']:.1f} s, "
             f"{res.param_counts[1]['free parameters']:,} params"}
    res.seconds = time.perf_counter() - t0
    return res


def _volume_stability(train, S: int, n_pts: int, size: str, seed: int) -> list[dict]:
    from .fit.volume import fit_volume

    small = max(8, S // 4)
    imgs, sils, cams = train.images, train.silhouettes, train.cameras
    nan_i = imgs.copy()
    nan_i[0, 0, 0, 0] = np.nan
    cases = {
        "one view only": (imgs[:1], sils[:1], cams[[0]]),
        "black images, empty silhouettes": (np.zeros_like(imgs), np.zeros_like(sils), cams),
        "NaN in an image": (nan_i, sils, cams),
        "silhouettes of the wrong size": (imgs, sils[:, :-1], cams),
    }
    rows = []
    for method, kw in (("tutorial", {"method": "tutorial", "n_iter": _pick(size, 2, 10, 30),
                                     "batch_size": 1}),
                       ("lbfgs", {"method": "lbfgs", "levels": (small,),
                                  "iterations": _pick(size, 2, 10, 30)})):
        for case, (i_, s_, c_) in cases.items():  # failure cases
            fit, err = _try(fit_volume, i_, s_, c_, volume_size=small,
                            n_pts_per_ray=max(16, n_pts // 4), seed=seed, **kw)
            rows.append(_fit_row(method, case, fit, err, lambda f: {
                "NaN in volume": bool(np.isnan(f.volume.densities).any()),
                "occupied voxels": int(f.n_occupied_voxels),
                "seconds": round(f.seconds, 2)}))
    return rows


# --------------------------------------------------------------------------------------------
# 6. fit a neural radiance field
# --------------------------------------------------------------------------------------------


def _nerf_settings(size: str) -> dict:
    budget = _pick(size, None, 20.0, None)
    scene = {"preset": "scene", "n_iter": _pick(size, 2, 20000, 20000),
             "n_pts_per_ray": _pick(size, 8, 64, 128)}
    if size == "tiny":
        scene.update(n_rays_per_image=32, hull_resolution=24)
    return {
        "n_views": _pick(size, 4, 20, 40), "image_size": _pick(size, 24, 64, 128),
        "n_heldout": _pick(size, 1, 2, 8), "heldout_size": _pick(size, 24, 32, 128),
        "tutorial": {"preset": "tutorial", "n_iter": _pick(size, 2, 3000, 3000),
                     "n_rays_per_image": _pick(size, 32, 128, 750),
                     "n_pts_per_ray": _pick(size, 8, 64, 128)},
        "scene": scene,
        "time_budget": budget,
        "eval_every": _pick(size, 2, budget / 5 if budget else None, None),
    }


def step_nerf(out, size: str = "default", *, progress: bool = True, seed: int = 0
              ) -> StepResult:
    """Fit a neural radiance field: the tutorial's network and recipe, and geofit's scene-sized one.

    Parameters
    ----------
    out : path
        The run's output folder; the step writes into ``out/nerf``.
    size : {"tiny", "default", "full"}
        ``"full"``: 40 views of 128 px, 3000 steps of the tutorial's recipe;
        ``"default"``: 20 views of 64 px, 64 samples per ray (the tutorial recipe with 128
        rays per view instead of 750), each method stopped after 20 s of solver time, PSNR on
        held-out renders of 32 px.
    progress : bool
        A progress bar over the fits.
    seed : int
        Initialisation, view and ray choices.

    Returns
    -------
    StepResult
    """
    from .fit.nerf import fit_nerf, render_nerf

    res, d, t0 = _begin(out, "nerf", size)
    cfg = _nerf_settings(size)
    img = cfg["image_size"]
    train, test, name = _cow_views(cfg["n_views"], img, cfg["n_heldout"], cfg["heldout_size"])
    res.config = {"object": name, "training views": cfg["n_views"],
                  "held-out views": cfg["n_heldout"], "image size": img,
                  "held-out image size": cfg["heldout_size"],
                  "PyTorch3D recipe": _settings_text(cfg["tutorial"]),
                  "geofit": _settings_text(cfg["scene"]),
                  "time budget per method (s)": cfg["time_budget"]}
    res.description = (
        "A radiance field (MLP on harmonic embeddings) is fitted to the renders with the "
        "emission-absorption raymarcher. Accuracy: PSNR of full renders of held-out views "
        "(azimuths half-way between the training views, elevations 0 and 20 degrees). Model "
        "size: the network's weights.")
    labels = {"tutorial": "PyTorch3D recipe: 60 frequencies, 2 x 256 Softplus, MC rays",
              "scene": "geofit: scene-sized network, visual hull, density grid"}
    bar = _bar(progress, len(labels), "nerf")
    fits = {}
    for key, label in labels.items():  # methods
        kw = dict(cfg[key])
        fit = fit_nerf(train.images, train.silhouettes, train.cameras, held_out=test,
                       time_budget=cfg["time_budget"], eval_every=cfg["eval_every"], seed=seed,
                       **kw)
        fits[key] = fit
        _record_fit(res, d, key, label, fit, ("psnr",),
                    final={"seconds": fit.seconds, "psnr": fit.psnr, "n_params": fit.n_params},
                    config={k: repr(v) for k, v in kw.items()})
        np.savez_compressed(d / f"{key}_weights.npz", **fit.field.params)
        res.files[f"{key} weights"] = d / f"{key}_weights.npz"
        res.metrics.append({"method": label, "status": fit.status,
                            "seconds": round(fit.seconds, 2), "iterations": fit.n_iterations,
                            "held-out PSNR (dB)": fit.psnr,
                            "samples per ray": round(fit.samples_per_ray, 1)})
        res.param_counts.append({"method": label, "network parameters": fit.n_params})
        bar.update(1)
    bar.close()
    renders = {}
    for key, fit in fits.items():
        renders[key] = fit.images if fit.images is not None else render_nerf(
            fit.field, test.cameras, cfg["heldout_size"], n_pts_per_ray=fit.config.n_pts_per_ray,
            occupancy=fit.occupancy)
    _heldout_comparison(res, d, test.images[:3], renders, fits,
                        f"Held-out views of the {name} and the fitted fields rendered from them.")
    res.charts["Speed and accuracy: held-out PSNR against solver time"] = \
        plot_accuracy_vs_time(_series(res.methods),
                              [{"metric": "psnr", "label": "held-out PSNR (dB)"}],
                              d / "speed_accuracy.png",
                              title=f"fit_nerf on the {name} ({size} size)")
    res.stability = _nerf_stability(train, size, seed)
    pt, gf = res.metrics
    res.headline = {
        _P3D: f"PSNR {pt['held-out PSNR (dB)'] or float('nan'):.1f} dB in {pt['seconds']:.1f} s, "
              f"{res.param_counts[0]['network parameters']:,} params",
        _GF: f"PSNR {gf['held-out PSNR (dB)'] or float('nan'):.1f} dB in {gf['seconds']:.1f} s, "
             f"{res.param_counts[1]['network parameters']:,} params"}
    res.seconds = time.perf_counter() - t0
    return res


def _nerf_stability(train, size: str, seed: int) -> list[dict]:
    from .fit.nerf import fit_nerf

    imgs, sils, cams = train.images, train.silhouettes, train.cameras
    nan_i = imgs.copy()
    nan_i[0, 0, 0, 0] = np.nan
    n_iter = _pick(size, 2, 4, 50)
    cases = {
        "one view only": (imgs[:1], sils[:1], cams[[0]], {}),
        "black images, empty silhouettes": (np.zeros_like(imgs), np.zeros_like(sils), cams, {}),
        "NaN in an image": (nan_i, sils, cams, {}),
        "learning rate x1000": (imgs, sils, cams, {"lr_x": 1000.0}),
    }
    rows = []
    for method in ("tutorial", "scene"):
        for case, (i_, s_, c_, extra) in cases.items():  # failure cases
            kw = {"preset": method, "n_iter": n_iter, "n_pts_per_ray": 16,
                  "n_rays_per_image": 64}
            if "lr_x" in extra:
                kw["lr"] = (1e-3 if method == "tutorial" else 5e-3) * extra["lr_x"]
            fit, err = _try(fit_nerf, i_, s_, c_, seed=seed, **kw)
            rows.append(_fit_row(method, case, fit, err, lambda f: {
                "NaN weights": bool(np.isnan(f.field.get_flat()).any()),
                "seconds": round(f.seconds, 2)}))
    return rows


# --------------------------------------------------------------------------------------------
# The runner
# --------------------------------------------------------------------------------------------

#: The steps in order: name -> (function, title, PyTorch3D tutorial).
STEPS: dict[str, tuple[Callable[..., StepResult], str, str]] = {
    "fit_mesh": (step_fit_mesh, "1. Fit a mesh to a mesh", "deform_source_mesh_to_target_mesh"),
    "render_mesh": (step_render_mesh, "2. Render textured meshes", "render_textured_meshes"),
    "render_points": (step_render_points, "3. Render coloured point clouds",
                      "render_colored_points"),
    "fit_views": (step_fit_views, "4. Fit a mesh to multi-view images", "fit_textured_mesh"),
    "fit_volume": (step_fit_volume, "5. Fit a voxel volume", "fit_textured_volume"),
    "nerf": (step_nerf, "6. Fit a neural radiance field", "fit_simple_neural_radiance_field"),
}


def run_step(name: str, out, size: str = "default", *, progress: bool = True,
             seed: int = 0) -> StepResult:
    """Run one step; an exception becomes a ``"failed: ..."`` result (traceback in error.txt).

    Parameters
    ----------
    name : str
        A key of :data:`STEPS`.
    out : path
        The run's output folder.
    size : {"tiny", "default", "full"}
    progress : bool
    seed : int

    Returns
    -------
    StepResult
        Never raises for a failure inside the step.

    Raises
    ------
    ValueError
        For an unknown step name or size.
    """
    check_choice(name, "name", tuple(STEPS))
    check_choice(size, "size", SIZES)
    fn, title, tutorial = STEPS[name]
    t0 = time.perf_counter()
    try:
        return fn(out, size, progress=progress, seed=seed)
    except Exception as exc:  # noqa: BLE001 - a failed step is reported, never dropped
        d = Path(out) / name
        d.mkdir(parents=True, exist_ok=True)
        (d / "error.txt").write_text(traceback.format_exc(), encoding="utf-8")
        res = StepResult(name, title, tutorial, status=_failure(exc), size=size,
                         seconds=time.perf_counter() - t0)
        res.files["traceback"] = d / "error.txt"
        res.headline = {_P3D: "", _GF: ""}
        return res


def _size_chart(steps: Sequence[StepResult], path: Path) -> Path | None:
    sizes = {}
    tutorial_labels = []
    for s in steps:  # workflows
        for m in s.methods:
            n = m["final"].get("n_params")
            if not n:
                continue
            label = f"{s.name}: {m['name']}"
            sizes[label] = n
            if m["name"] == "tutorial":
                tutorial_labels.append(label)
    if not sizes:
        return None
    return plot_model_sizes(sizes, path, highlight=tutorial_labels,
                            title="Free parameters of each fitted model\n"
                                  "(orange: PyTorch3D's recipe, blue: geofit's methods)")


def _data_note() -> str:
    """Which tutorial files were found, and where (the data the run used)."""
    from .data import data_dir, find

    instead = {"dolphin/dolphin.obj": "the procedural target used instead",
               "cow_mesh/cow.obj": "the procedural textured mesh used instead",
               _BRIDGE: "the tutorial's cloud not rendered"}
    found = {n: find(n) for n in instead}
    parts = [f"{n} from {p.parent.parent}" if p is not None else f"{n} not found ({instead[n]})"
             for n, p in found.items()]
    return f"Data folder {data_dir()}: " + "; ".join(parts) + "."


def run_tutorials(out, *, size: str = "default", only: Sequence[str] | None = None,
                  progress: bool = True, seed: int = 0, command: str = "",
                  gallery=None) -> TutorialsRun:
    """Run the workflows and write the report.

    Parameters
    ----------
    out : path
        Output folder (created): one sub-folder per step, ``report.html``, ``report.md``,
        ``report.json`` and ``model_sizes.png``.
    size : {"tiny", "default", "full"}
        See the module docstring.
    only : sequence of str, optional
        Step names to run (default all of :data:`STEPS`, in order).
    progress : bool
        tqdm progress bars (on stderr).
    seed : int
        Seed of every random choice.
    command : str
        The command line, shown in the report.
    gallery : path, optional
        Also copy the figures into this folder under stable names, with a README.md (see
        :func:`geofit.report.write_gallery`), e.g. ``docs/tutorials`` for the README.

    Returns
    -------
    TutorialsRun

    Raises
    ------
    ValueError
        For an unknown size or step name.
    """
    from .report import write_report

    check_choice(size, "size", SIZES)
    names = list(STEPS) if only is None else list(only)
    if not names:
        raise ValueError("only: expected at least one step name, got none")
    for n in names:
        check_choice(n, "only", tuple(STEPS))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    steps = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(names), desc="geofit tutorials", unit="step", dynamic_ncols=True)
    for n in names:  # workflows
        if bar is not None:
            bar.set_postfix_str(n)
        steps.append(run_step(n, out, size, progress=progress, seed=seed))
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    charts = {}
    chart = _size_chart(steps, out / "model_sizes.png")
    if chart is not None:
        charts["Model size: free parameters of each method's fitted model (log scale)"] = chart
    seconds = time.perf_counter() - t0
    notes = [f"{sum(s.ok for s in steps)} of {len(steps)} workflows ran.", _data_note()]
    failed = [s.name for s in steps if not s.ok]
    if failed:
        notes.append("Failed: " + ", ".join(failed) + " (see each section).")
    report = dict(write_report(steps, out, command=command, size=size, seconds=seconds,
                               charts=charts, notes=notes))
    if gallery is not None:
        from .report import write_gallery

        report["gallery"] = write_gallery(steps, gallery, command=command, charts=charts,
                                          size=size, seconds=seconds, notes=notes[1:])
    return TutorialsRun(steps, seconds, out, report, charts)


def _load_json(path) -> dict:  # pragma: no cover - convenience for notebooks
    return json.loads(Path(path).read_text(encoding="utf-8"))
