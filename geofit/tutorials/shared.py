"""What the tutorial steps share: the result types, the step titles, the report helpers, the cow
renders. Public within :mod:`geofit.tutorials` (the package API is its ``__all__``)."""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._json import json_safe
from .._validate import check_choice
from ..cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform
from ..data import load_textured_mesh
from ..datasets import held_out_views, tutorial_views
from ..fit.history import FitHistory
from ..render import (
    BlendParams,
    EmissionAbsorptionRaymarcher,
    HardPhongShader,
    MeshRasterizer,
    MeshRenderer,
    NDCMultinomialRaysampler,
    PointLights,
    RasterizationSettings,
    TexturesFlat,
)
from ..render.volume import VolumeRenderer
from ..structures import Mesh, MultiViewDataset
from ..viz import Series, image_panel, plot_accuracy_vs_time, save_png

__all__ = ["SIZES", "StepResult", "TutorialsRun"]


#: Run sizes: test-sized, the reduced default, the tutorials' own.
SIZES = ("tiny", "default", "full")

#: The steps in order: name -> (title, PyTorch3D tutorial); :data:`geofit.tutorials.STEPS` adds
#: each step's function.
STEP_TITLES: dict[str, tuple[str, str]] = {
    "fit_mesh": ("1. Fit a mesh to a mesh", "deform_source_mesh_to_target_mesh"),
    "render_mesh": ("2. Render textured meshes", "render_textured_meshes"),
    "render_points": ("3. Render coloured point clouds", "render_colored_points"),
    "fit_views": ("4. Fit a mesh to multi-view images", "fit_textured_mesh"),
    "fit_volume": ("5. Fit a voxel volume", "fit_textured_volume"),
    "nerf": ("6. Fit a neural radiance field", "fit_simple_neural_radiance_field"),
}

# the two columns of the report's summary table
P3D_COLUMN = "PyTorch3D's recipe (run by geofit)"
GEOFIT_COLUMN = "geofit's method"


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

        return json_safe({
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


def pick_size(size: str, tiny, default, full):
    return {"tiny": tiny, "default": default, "full": full}[size]


def recipe_cut(done, full, unit: str = "steps") -> str:
    """``" (recipe cut to 300 of 2000 steps)"`` when fewer than the recipe's ``full`` ran (a
    smaller size or a time budget), else ``""``: appended to a baseline's row in the table and
    the summary, so a shortened baseline is marked where its numbers are."""
    if done is None or full is None or int(done) >= int(full):
        return ""
    return f" (recipe cut to {int(done)} of {int(full)} {unit})"


def method_record(name: str, label: str, *, seconds=(), curve=None, final=None, status="",
            message="", config=None) -> dict:
    """A benchmark-style method record (the layout of benchmarks/_harness.py's MethodRun)."""
    return {"name": name, "label": label, "status": status, "message": message,
            "config": dict(config or {}), "final": dict(final or {}),
            "curve": {"seconds": [float(s) for s in seconds],
                      **{k: [float(x) for x in v] for k, v in (curve or {}).items()}}}


def method_series(methods: Sequence[dict]) -> list[Series]:
    return [Series(m["label"], m["curve"]["seconds"],
                   {k: v for k, v in m["curve"].items() if k != "seconds"}) for m in methods]


def failure_text(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else "(no message)"
    return f"failed: {type(exc).__name__}: {msg}"


def try_call(fn: Callable[..., Any], *args, **kwargs) -> tuple[Any, str | None]:
    """``(fn(*args, **kwargs), None)`` or ``(None, "failed: <exception>: <message>")``."""
    try:
        return fn(*args, **kwargs), None
    except Exception as exc:  # noqa: BLE001 - stability rows report every failure
        return None, failure_text(exc)


def progress_bar(progress: bool, total: int, desc: str):
    """A tqdm progress bar over ``total`` steps; a disabled one (no output) without ``progress``."""
    from tqdm import tqdm  # kept local: tqdm, loaded only when used (start-up)

    return tqdm(total=total, desc=desc, leave=False, dynamic_ncols=True, disable=not progress)


def look_at_cameras(dist, elev, azim, *, ortho: bool = False, **kw):
    R, T = look_at_view_transform(dist, elev, azim)
    if ortho:
        return FoVOrthographicCameras(R=R, T=T, **kw)
    return FoVPerspectiveCameras(R=R, T=T, **kw)


def shade_mesh(mesh, cameras, image_size: int, *, color=(0.72, 0.75, 0.8), light=(2.0, 2.0, 2.0),
                background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(N, H, W, 3) Phong render of an untextured mesh in a flat colour (one per camera)."""
    m = Mesh(mesh.verts, mesh.faces, TexturesFlat(list(color)))
    n = len(cameras)
    renderer = MeshRenderer(MeshRasterizer(cameras, RasterizationSettings(image_size=image_size)),
                            HardPhongShader(lights=PointLights(location=[list(light)]),
                                            blend_params=BlendParams(background_color=background)))
    return np.asarray(renderer(m.extend(n) if n > 1 else m)[..., :3], dtype=np.float64)


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a) > 0.5, np.asarray(b) > 0.5
    union = int((a | b).sum())
    return 1.0 if union == 0 else float((a & b).sum() / union)


def write_history(history: FitHistory, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    history.to_json(path)
    return path


def accuracy_curve(history: FitHistory, names: Mapping[str, str]) -> tuple[list, dict]:
    """Checkpoint seconds and the metric columns ``{new_name: values}`` of a history."""
    a = history.as_arrays()
    curve = {new: a["metrics"][old].tolist() for old, new in names.items()
             if old in a["metrics"]}
    return a["checkpoint_seconds"].tolist(), curve


def begin_textured_step(out, name: str, size: str):
    """:func:`begin_step` for the rendering steps, plus the textured default mesh (the cow when
    found): ``(res, folder, t0, data, mesh)``, ``mesh`` normalised as the tutorials do."""
    res, d, t0 = begin_step(out, name, size)
    data = load_textured_mesh()
    return res, d, t0, data, data.mesh.normalize().mesh


def begin_step(out, name: str, size: str) -> tuple[StepResult, Path, float]:
    """Check ``size``, start the clock, create ``out/<name>``: the empty result, folder, start."""
    check_choice(size, "size", SIZES)
    t0 = time.perf_counter()
    d = Path(out) / name
    d.mkdir(parents=True, exist_ok=True)
    title, tutorial = STEP_TITLES[name]
    return StepResult(name, title, tutorial, size=size), d, t0


def settings_text(settings: Mapping) -> str:
    """``"k=v, k=v"`` of a settings dict (the report's config cells)."""
    return ", ".join(f"{k}={v}" for k, v in settings.items())


def views_config(name: str, n_train: int, n_heldout: int, image_size, tutorial: Mapping,
                  geofit: Mapping, **extra) -> dict:
    """The configuration table of a multi-view step: the object, the views, the image size,
    both recipes' settings and ``extra`` rows (label -> value), in that order."""
    return {"object": name, "training views": n_train, "held-out views": n_heldout,
            "image size": image_size, **extra, "PyTorch3D recipe": settings_text(tutorial),
            "geofit": settings_text(geofit)}


def record_fit(res: StepResult, d: Path, key: str, label: str, fit, metrics: Sequence[str], *,
                final: dict, config: Mapping) -> None:
    """Add one fit's method record (curves of ``metrics`` from its history) and its history."""
    seconds, curve = accuracy_curve(fit.history, {k: k for k in metrics})
    res.methods.append(method_record(key, label, seconds=seconds, curve=curve, final=final,
                               status=fit.status, message=fit.message, config=config))
    res.histories[key] = fit.history
    res.files[f"{key} history"] = write_history(fit.history, d / f"{key}_history.json")


def heldout_comparison(res: StepResult, d: Path, targets: np.ndarray, renders: Mapping,
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


def close_comparison(res: StepResult, d: Path, t0: float, *, chart: str, panels: list,
                      title: str, stability: list, headline: Callable[[dict, int], str]
                      ) -> StepResult:
    """Finish a recipe-against-method step: the speed/accuracy chart of ``res.methods``
    (``chart`` its heading, ``panels`` as :func:`geofit.viz.plot_accuracy_vs_time`), the
    stability rows, one headline per recipe (``headline(metrics, index)``) and the seconds."""
    res.charts[f"Speed and accuracy: {chart} against solver time"] = plot_accuracy_vs_time(
        method_series(res.methods), panels, d / "speed_accuracy.png", title=title)
    res.stability = stability
    res.headline = {P3D_COLUMN: headline(res.metrics[0], 0),
                    GEOFIT_COLUMN: headline(res.metrics[1], 1)}
    res.seconds = time.perf_counter() - t0
    return res


def close_psnr_step(res: StepResult, d: Path, t0: float, targets: np.ndarray, renders: Mapping,
                    fits: Mapping, *, subject: str, fitted: str, full_iters: int, params: str,
                    **close) -> StepResult:
    """Finish a step scored by held-out PSNR (volume, NeRF): :func:`heldout_comparison` of the
    ``fitted`` results of ``subject``, then :func:`close_comparison` (``close`` its keywords)
    with one headline per recipe, "PSNR .. dB in .. s, .. params" from
    ``res.param_counts[i][params]``, the tutorial's first, with what :func:`recipe_cut` says of
    its run against the tutorial's ``full_iters``."""
    heldout_comparison(res, d, targets, renders, fits,
                       f"Held-out views of the {subject} and the fitted {fitted} rendered from "
                       "them.")
    cut = recipe_cut(fits["tutorial"].n_iterations, full_iters)

    def headline(m: dict, i: int) -> str:
        value = m["held-out PSNR (dB)"]
        return (f"PSNR {float('nan') if value is None else value:.1f} dB in {m['seconds']:.1f} s, "
                f"{res.param_counts[i][params]:,} params" + (cut if i == 0 else ""))
    return close_comparison(res, d, t0, headline=headline, **close)


def run_cases(cases: Mapping[str, Callable[[], Any]]) -> list[dict]:
    """One stability row per case: ``str`` of what it returned, or how it failed."""
    rows = []
    for case, fn in cases.items():  # failure cases
        r, err = try_call(fn)
        rows.append({"case": case, "outcome": err if err is not None else str(r)})
    return rows


def fit_row(method: str, case: str, run: Callable[[], Any],
            measure: Callable[[Any], dict]) -> dict:
    """A fit's stability row: ``fit = run()``, then how it failed, or how it stopped and
    ``measure(fit)``."""
    fit, err = try_call(run)
    row = {"method": method, "case": case}
    if err is not None:
        row["outcome"] = err
    else:
        row.update(outcome="converged" if fit.converged else f"stopped: {fit.status}",
                   **measure(fit))
    return row


# --------------------------------------------------------------------------------------------
# Shared by 5 and 6: the tutorials' renders of the cow (black background, silhouettes)
# --------------------------------------------------------------------------------------------


def stability_views(images, silhouettes, cameras) -> MultiViewDataset:
    """A MultiViewDataset of the arrays (inside a stability run: bad arrays fail there)."""
    return MultiViewDataset(images=images, silhouettes=silhouettes, cameras=cameras)


def broken_views(train: MultiViewDataset) -> dict[str, tuple]:
    """The failure cases every views fit's stability table starts with: ``{case: (images,
    silhouettes, cameras)}`` for one view only, black images with empty silhouettes and a NaN
    in an image (made into data by :func:`stability_views` inside the run)."""
    imgs, sils, cams = train.images, train.silhouettes, train.cameras
    nan_i = imgs.copy()
    nan_i[0, 0, 0, 0] = np.nan
    return {
        "one view only": (imgs[:1], sils[:1], cams[[0]]),
        "black images, empty silhouettes": (np.zeros_like(imgs), np.zeros_like(sils), cams),
        "NaN in an image": (nan_i, sils, cams),
    }


def cow_views(n_views: int, image_size: int, n_heldout: int, heldout_size: int):
    """Training and held-out renders of the volume and NeRF tutorials (:mod:`geofit.datasets`).

    Training: ``tutorial_views(5)`` (elevation 0, azimuths around the cow, black background,
    0/1 silhouettes). Held out: views half-way between the training azimuths, at elevations 0
    and 20 degrees (20 only when a single view is asked for).
    """
    train = tutorial_views(5, num_views=n_views, image_size=image_size, num_held_out=0)
    elevations = (0.0, 20.0) if n_heldout >= 2 else (20.0,)
    test = held_out_views(num_views=n_views, elevations=elevations,
                          n_azimuths=max(1, n_heldout // len(elevations)),
                          image_size=heldout_size)
    return train, test, train.name


def render_volume_views(volume, cameras, image_size: int, n_pts: int) -> np.ndarray:
    r = VolumeRenderer(NDCMultinomialRaysampler(image_width=image_size, image_height=image_size,
                                                n_pts_per_ray=n_pts, min_depth=0.1,
                                                max_depth=3.0),
                       EmissionAbsorptionRaymarcher())
    return r(cameras, volume)[0]
