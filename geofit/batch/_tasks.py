"""What one Dask task does: load its own input, fit or render, write its outputs atomically.

Runs in a worker process. Everything here receives plain data (paths, dicts of settings) and
builds its own objects, so no Embree scene, Open3D object or big array crosses a process
boundary. Each fit is called with its defaults, the data plus only the options the user
gave (:data:`FIT_KEYWORDS`: when a fit's keywords change, that table changes here), so a
batch target fits exactly as ``geofit.fit_*`` and the command line do.
"""
from __future__ import annotations

import importlib
import json
import os
import socket
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_write as _atomic_write
from .._json import json_text
from .._threads import blas_threads, get_num_threads, set_num_threads
from ..cameras import FoVPerspectiveCameras, look_at_view_transform
from ..datasets import render_views, training_azimuths
from ..fit.volume import volume_metrics
from ..io import load_mesh, save_obj
from ..metrics import MeshEvaluator
from ..render import (
    HardPhongShader,
    MeshRasterizer,
    MeshRenderer,
    PointLights,
    RasterizationSettings,
)
from ..structures import Mesh, TexturesVertex
from ._options import (  # noqa: F401 - CAPTURE_MARKERS, MESH_SUFFIXES, is_capture: re-exported
    CAPTURE_MARKERS,
    MESH_SUFFIXES,
    PICTURE_FILE,
    RESULT_FILE,
    RESULT_SCHEMA,
    environment_cause,
    is_capture,
)

#: Held-out share of a capture without a split of its own: every ``HOLDOUT_EVERY``-th view.
HOLDOUT_EVERY = 8

#: Per task, the batch options passed on to the fit: ``{option: the fit's keyword}``, each only
#: when given (not None). Everything else is the fit's own default.
FIT_KEYWORDS: dict[str, dict[str, str]] = {
    "fit-mesh": {"recipe": "recipe", "time_budget": "time_budget", "seed": "seed"},
    "fit-views": {"recipe": "recipe", "time_budget": "time_budget", "seed": "seed"},
    "fit-volume": {"recipe": "recipe", "time_budget": "time_budget", "seed": "seed"},
    "fit-nerf": {"recipe": "recipe", "time_budget": "time_budget", "seed": "seed"},
}


# ------------------------------------------------------------------------------ small helpers
def atomic_write(path: Path, write: Callable[[Path], Any]) -> Path:
    """``write(tmp)`` to a temporary file beside ``path``, then ``os.replace`` it into place.

    The temporary name keeps the suffix (writers choose the format by it); a reader never sees
    a half-written file, and a crash leaves at most a hidden ``.*.tmp-*`` file.
    """
    return _atomic_write(path, write)  # the one atomic, durable write (fsync too)


def write_json(path: Path, data: dict) -> Path:
    """Write ``data`` as indented JSON, atomically (non-finite floats as strings)."""
    text = json_text(data)
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def _save_png(path: Path, image: np.ndarray) -> Path:
    from PIL import Image  # kept local: Pillow, loaded only when used (start-up)

    arr = (np.clip(np.asarray(image, np.float64), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return atomic_write(path, lambda p: Image.fromarray(arr).save(p))


def _save_mesh(path: Path, mesh) -> Path:
    plain = Mesh(mesh.verts, mesh.faces)
    return atomic_write(path, lambda p: save_obj(p, plain))


def _save_npz(path: Path, **arrays) -> Path:
    return atomic_write(path, lambda p: np.savez_compressed(p, **arrays))


def _rows(*rows: np.ndarray) -> np.ndarray:
    """Stack rows of (n, H, W, 3) images into one picture (each row tiled left to right)."""
    return np.concatenate([np.concatenate(list(r[..., :3]), axis=1) for r in rows], axis=0)


def limit_threads(n: int) -> int:
    """Limit this worker's compute threads to ``n``: :func:`geofit.set_num_threads` (geofit's
    pool for ray casting and rendering, BLAS through threadpoolctl, Open3D), and
    ``GEOFIT_NUM_THREADS`` / ``OMP_NUM_THREADS`` for anything that reads them later.
    Returns the count geofit reports back (:func:`geofit.get_num_threads`)."""
    os.environ["GEOFIT_NUM_THREADS"] = str(n)
    os.environ["OMP_NUM_THREADS"] = str(n)
    set_num_threads(n)
    return int(get_num_threads())


#: What a worker imports before its first task (:func:`warm_up`): the geofit modules of each
#: task and the libraries they load on first use (Open3D alone pulls in ~800 modules). Measured
#: in a fresh process: the first fit-mesh task took 1.4 s against 0.19 s for the next ones
#: without these imports, 0.29 s with them.
WARM_MODULES: dict[str, tuple[str, ...]] = {
    "fit-mesh": ("geofit.fit", "geofit.metrics", "scipy.optimize"),
    "render": (),
    "fit-views": ("geofit.fit.views", "geofit.datasets", "scipy.optimize"),
    "fit-volume": ("geofit.fit.volume", "geofit.datasets"),
    "fit-nerf": ("geofit.fit.nerf", "geofit.datasets"),
}
#: This process's :func:`warm_up` reports by task (a task records whether it ran warm).
_WARMED: dict[str, dict] = {}

_WARM_COMMON = ("geofit.io", "geofit.render", "geofit.raycast", "geofit.structures", "open3d",
                "PIL.Image")


def warm_up(task: str, threads: int) -> dict:
    """Prepare this worker process for ``task``: limit its compute threads to ``threads``
    (:func:`limit_threads`) and import what the task's first target would otherwise import.

    Run once per worker before any target (``geofit.batch`` registers it as a Dask worker
    plugin), so that no task pays the imports. A module that cannot be imported is skipped
    (the task itself then reports the error). Returns ``{"seconds", "threads", "pid",
    "blas_threads", "skipped"}`` (``blas_threads``: each loaded BLAS's thread count, read back
    by threadpoolctl), also kept in ``_WARMED[task]``.
    """
    t = time.perf_counter()
    got = limit_threads(int(threads))
    skipped = []
    for name in _WARM_COMMON + WARM_MODULES.get(task, ()):
        try:
            importlib.import_module(name)
        except ImportError:
            skipped.append(name)
    got = limit_threads(int(threads))  # again: the imports may have loaded another BLAS
    report = {"seconds": time.perf_counter() - t, "threads": got, "pid": os.getpid(),
              "blas_threads": blas_threads(), "skipped": skipped}
    _WARMED[task] = report
    return report


# ------------------------------------------------------------------------------ inputs
def _load_mesh(path: Path, textures: bool = False):
    mesh = load_mesh(path, load_textures=textures) if path.suffix.lower() == ".obj" \
        else load_mesh(path)
    if mesh.n_faces == 0:
        raise ValueError(f"{path}: the mesh has no faces")
    return mesh


def _coloured(mesh):
    """The mesh normalised (as the tutorials), with vertex colours from its normals when it has
    no texture, so that RGB renders carry information."""
    m = mesh.normalize().mesh
    if m.textures is None:
        m = Mesh(m.verts, m.faces, TexturesVertex(0.25 + 0.5 * np.abs(m.verts_normals)))
    return m


def _load_capture(folder: Path, background: tuple):
    """A capture folder -> (images (N, H, W, 3), silhouettes (N, H, W), cameras), RGBA images
    composited over ``background`` (black for the volume and NeRF fits, white for the mesh).

    The one place that knows ``geofit.io.load_views``' contract (a dataset with
    ``images``, ``silhouettes`` and ``cameras``).
    """
    from ..io import load_views

    ds = load_views(folder, background=background)
    sils = None if ds.silhouettes is None else np.asarray(ds.silhouettes, np.float64)  # unknown
    return np.asarray(ds.images, np.float64)[..., :3], sils, ds.cameras


def _split(images, silhouettes, cameras):
    """Every :data:`HOLDOUT_EVERY`-th view held out (at least one view each side)."""
    n = len(images)
    if n < 2:
        raise ValueError(f"a capture needs at least 2 views, got {n}")
    held = np.zeros(n, bool)
    held[HOLDOUT_EVERY // 2::HOLDOUT_EVERY] = True
    if not held.any():
        held[n // 2] = True
    tr, te = np.flatnonzero(~held), np.flatnonzero(held)
    return tuple((images[i], None if silhouettes is None else silhouettes[i], cameras[i])
                 for i in (tr, te))


def _tutorial5_views(path: Path, s: dict):
    """Training and held-out (images, silhouettes, cameras) for fit-volume / fit-nerf: a
    capture folder, or renders of a mesh file as the tutorial renders the cow (azimuths around
    it at elevation 0, black background; held out: the azimuths half-way, elevation 20)."""
    if path.is_dir():
        return _split(*_load_capture(path, (0.0, 0.0, 0.0))) + (None,)
    mesh = _coloured(_load_mesh(path, textures=True))
    az = training_azimuths(s["views"])
    train = render_views(mesh, az, 0.0, image_size=s["image_size"])
    step = 360.0 / s["views"]
    az_h = (az[: max(1, min(s["heldout"], s["views"]))] + step / 2.0)
    test = render_views(mesh, az_h, 20.0, image_size=s["image_size"])
    return ((train.images, train.silhouettes, train.cameras),
            (test.images, test.silhouettes, test.cameras), mesh)


# ------------------------------------------------------------------------------ adapters
def _fit_kwargs(task: str, s: dict) -> dict:
    """The fit's keywords of ``task`` from the settings ``s`` (:data:`FIT_KEYWORDS`), with
    progress off (a worker has no terminal)."""
    return {**{kw: s[opt] for opt, kw in FIT_KEYWORDS[task].items() if s.get(opt) is not None},
            "progress": False}


def _dataset(images, silhouettes, cameras):
    from ..structures import MultiViewDataset

    return MultiViewDataset(images=images, silhouettes=silhouettes, cameras=cameras)


def _task_fit_mesh(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    t = time.perf_counter()
    target = _load_mesh(path)
    clock["load_seconds"] = time.perf_counter() - t
    from ..fit import fit_mesh

    res = fit_mesh(target, **_fit_kwargs("fit-mesh", s))
    clock["fit_seconds"] = res.seconds
    t = time.perf_counter()
    m = MeshEvaluator(target, taus=(0.01,), normalize=True, seed=0).evaluate(res.mesh)
    clock["eval_seconds"] = time.perf_counter() - t
    _save_mesh(dest / "fit.obj", res.mesh)
    pics = _render_pair(target, res.mesh)
    _save_png(dest / PICTURE_FILE, pics)
    return {"fit": res, "metrics": m.as_dict(), "outputs": {"mesh": "fit.obj"},
            "extra": {"n_verts": res.n_verts, "n_faces": res.mesh.n_faces,
                      "target_verts": target.n_verts, "target_faces": target.n_faces}}


def _render_pair(target, fitted, size: int = 160):
    """Target (top) and fitted mesh (bottom) from three directions, both in the target's
    normalised frame."""
    norm = target.normalize()
    fit_n = Mesh((fitted.verts - norm.center) / norm.scale, fitted.faces)
    return _rows(_views(norm.mesh, 3, size), _views(fit_n, 3, size))


def _views(mesh, n: int, size: int, *, dist: float = 2.7, elev: float = 20.0):
    """``n`` Phong renders (n, size, size, 4) of ``mesh`` at azimuths spread around it."""
    az = np.linspace(0.0, 360.0, n, endpoint=False) + 30.0
    R, T = look_at_view_transform(dist, np.full(n, elev), az)
    cams = FoVPerspectiveCameras(R=R, T=T)
    renderer = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=size)),
                            HardPhongShader(cameras=cams,
                                            lights=PointLights(location=[[0.0, 2.0, -3.0]])))
    return np.asarray(renderer(mesh.extend(n) if n > 1 else mesh), np.float64)


def _task_render(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    t = time.perf_counter()
    mesh = _load_mesh(path, textures=True).normalize().mesh
    clock["load_seconds"] = time.perf_counter() - t
    t = time.perf_counter()
    images = _views(mesh, s["views"], s["image_size"], dist=s["dist"], elev=s["elev"])
    clock["fit_seconds"] = time.perf_counter() - t
    outputs = {}
    for i, img in enumerate(images):
        name = f"view_{i:02d}.png"
        _save_png(dest / name, img[..., :3])
        outputs[f"view_{i}"] = name
    _save_png(dest / PICTURE_FILE, _rows(images))
    coverage = float((images[..., 3] > 0).mean())
    pixels = images.shape[0] * images.shape[1] * images.shape[2]
    return {"fit": None, "metrics": {"coverage": coverage,
                                     "mpix_per_s": pixels / max(clock["fit_seconds"], 1e-9)
                                     / 1e6},
            "outputs": outputs, "extra": {"n_verts": mesh.n_verts, "n_faces": mesh.n_faces}}


def _task_fit_views(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    from ..structures import MultiViewDataset
    from ..datasets import tutorial_views
    from ..fit.views import ViewsEvaluator

    t = time.perf_counter()
    if path.is_dir():
        (tr, te) = _split(*_load_capture(path, (1.0, 1.0, 1.0)))
        train, heldout, truth = (MultiViewDataset(images=tr[0], silhouettes=tr[1], cameras=tr[2]),
                                 MultiViewDataset(images=te[0], silhouettes=te[1],
                                                  cameras=te[2]), None)
    else:
        train = tutorial_views(4, mesh=_coloured(_load_mesh(path, textures=True)),
                               num_views=s["views"], image_size=s["image_size"],
                               num_held_out=s["heldout"], name=path.stem)
        heldout, truth = train.held_out, train.mesh
    clock["load_seconds"] = time.perf_counter() - t
    from ..fit import fit_mesh_to_views

    fit = fit_mesh_to_views(train, **_fit_kwargs("fit-views", s))
    clock["fit_seconds"] = fit.seconds
    t = time.perf_counter()
    colors = fit.colors if fit.colors is not None else np.full((fit.mesh.n_verts, 3), 0.7)
    ev = ViewsEvaluator(heldout, truth, taus=(0.01,))
    # the result as it is (its UV texture by default), the vertex colours without one
    metrics = ev(fit.mesh) if fit.mesh.textures is not None else ev(fit.mesh, colors)
    clock["eval_seconds"] = time.perf_counter() - t
    _save_mesh(dest / "fit.obj", fit.mesh)
    _save_npz(dest / "fit_colors.npz", verts=fit.mesh.verts, faces=fit.mesh.faces,
              colors=colors)
    k = min(4, len(heldout))
    pred = fit.render(heldout, n_views=k)
    target_rgb = heldout.images[:k] if heldout.images is not None else \
        np.repeat(heldout.silhouettes[:k, ..., None], 3, axis=-1)
    _save_png(dest / PICTURE_FILE, _rows(target_rgb, pred))
    return {"fit": fit, "metrics": metrics,
            "outputs": {"mesh": "fit.obj", "colors": "fit_colors.npz"},
            "extra": {"n_verts": fit.mesh.n_verts, "stages": fit.stages}}


def _task_fit_volume(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    t = time.perf_counter()
    (tr, te, _) = _tutorial5_views(path, s)
    clock["load_seconds"] = time.perf_counter() - t
    from ..fit import fit_volume

    res = fit_volume(_dataset(*tr), **_fit_kwargs("fit-volume", s))
    clock["fit_seconds"] = res.seconds
    t = time.perf_counter()
    m = volume_metrics(res.volume, te[0], te[1], te[2])
    clock["eval_seconds"] = time.perf_counter() - t
    vol = res.volume
    _save_npz(dest / "volume.npz", densities=vol.densities, features=vol.features,
              voxel_size=vol.voxel_size, volume_translation=vol.volume_translation)
    k = min(4, len(te[0]))
    _save_png(dest / PICTURE_FILE, _rows(te[0][:k], np.asarray(m.images)[:k]))
    return {"fit": res, "metrics": {"psnr": m.psnr, "iou": m.iou},
            "outputs": {"volume": "volume.npz"},
            "extra": {"n_active_voxels": res.n_active_voxels}}


def _task_fit_nerf(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    t = time.perf_counter()
    (tr, te, _) = _tutorial5_views(path, s)
    clock["load_seconds"] = time.perf_counter() - t
    from ..fit import fit_nerf

    train = _dataset(*tr)
    train.held_out = _dataset(*te)
    res = fit_nerf(train, **_fit_kwargs("fit-nerf", s))
    clock["fit_seconds"] = res.seconds
    _save_npz(dest / "nerf_field.npz", **res.field.params, config=json.dumps(asdict(res.config)))
    psnr = -1.0 if res.psnr is None else float(res.psnr)
    images = res.images
    if images is None:  # the fit's time budget left its final held-out render out
        from ..metrics import psnr as psnr_of

        images = res.render(train.held_out.cameras, te[0].shape[1:3])
        psnr = float(psnr_of(np.clip(images[..., :3], 0.0, 1.0), te[0]))
    k = min(4, len(te[0]))
    _save_png(dest / PICTURE_FILE, _rows(te[0][:k], np.asarray(images)[:k]))
    return {"fit": res, "metrics": {"psnr": psnr}, "outputs": {"weights": "nerf_field.npz"},
            "extra": {"samples_per_ray": res.samples_per_ray}}


ADAPTERS: dict[str, Callable[[Path, Path, dict, dict], dict]] = {
    "fit-mesh": _task_fit_mesh,
    "render": _task_render,
    "fit-views": _task_fit_views,
    "fit-volume": _task_fit_volume,
    "fit-nerf": _task_fit_nerf,
}


# ------------------------------------------------------------------------------ the task
def verdict(fit, accuracy, settings: dict) -> dict | None:
    """None when a target's fit counts as done, else its error ``{"type", "message"}``.

    Done means: the fit ended well by its own account (``fit.ok``: not failed, non-finite or
    diverged; and ``fit.accepted`` when the result has it), it made progress (at least one
    solver step: a fit whose time budget ran out before its first step returns its start and
    is not a result), and its accuracy metric is finite. ``fit`` None (a render) is done.
    """
    if fit is None:
        return None
    if not fit.ok or getattr(fit, "accepted", True) is False:
        return {"type": "FitStatus",
                "message": f"the fit ended with status {fit.status!r}: {fit.message}"}
    steps = int(getattr(fit, "n_iterations", 0) or 0)
    if steps < 1:
        if fit.status == "time_budget":
            budget = settings.get("time_budget")
            limit = f"of {budget:g} s " if budget is not None else ""
            why = f"its time budget {limit}ran out before its first step"
        else:
            why = f"it ended with status {fit.status!r} ({fit.message})"
        return {"type": "NoProgress", "message": f"the fit made no step: {why}"}
    if accuracy is not None and not np.isfinite(accuracy):
        return {"type": "FitStatus", "message": f"the fit's accuracy is {accuracy}"}
    return None


def run_target(spec: dict) -> dict:
    """Run one target on this process and write ``<out>/<name>/result.json``.

    ``spec`` holds ``task``, ``path``, ``name``, ``out``, ``settings``, ``settings_hash``,
    ``threads`` and ``accuracy_key``. Never raises for a failure of the target itself: an
    exception is recorded (status ``"failed"``, error type, message and traceback) and the
    record is returned. The returned record is ``result.json`` less the history.
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    started = time.time()
    threads = limit_threads(int(spec["threads"]))  # as read back from geofit
    dest = Path(spec["out"]) / spec["name"]
    dest.mkdir(parents=True, exist_ok=True)
    clock = {"load_seconds": 0.0, "fit_seconds": 0.0, "eval_seconds": 0.0}
    record: dict[str, Any] = {
        "schema": RESULT_SCHEMA, "name": spec["name"], "target": spec["path"],
        "task": spec["task"], "settings": spec["settings"],
        "settings_hash": spec["settings_hash"], "host": socket.gethostname(),
        "pid": os.getpid(), "threads": threads,
        # the worker ran warm_up for this task before it (imports not counted in "seconds")
        "warm": spec["task"] in _WARMED,
        "blas_threads": _WARMED.get(spec["task"], {}).get("blas_threads"),
    }
    history = None
    try:
        out = ADAPTERS[spec["task"]](Path(spec["path"]), dest, spec["settings"], clock)
        fit = out["fit"]
        error = verdict(fit, out["metrics"].get(spec["accuracy_key"]), spec["settings"])
        record.update(
            status="ok" if error is None else "failed",
            message=("" if fit is None else f"{fit.status}: {fit.message}") if error is None
            else error["message"],
            error=error, cause=None if error is None else "target",
            fit_status=None if fit is None else fit.status,
            metrics=out["metrics"], n_params=0 if fit is None else int(fit.n_params),
            n_iterations=0 if fit is None else int(fit.n_iterations),
            outputs=out["outputs"], picture=PICTURE_FILE if (dest / PICTURE_FILE).exists()
            else None, **out["extra"])
        if fit is not None:
            history = fit.history.to_dict()
    except Exception as exc:  # noqa: BLE001 - a target's failure is data, the batch goes on
        record.update(status="failed", message=f"{type(exc).__name__}: {exc}",
                      error={"type": type(exc).__name__, "message": str(exc),
                             "traceback": traceback.format_exc(limit=8)},
                      cause="environment" if environment_cause(exc) else "target",
                      fit_status=None, metrics={}, n_params=0, n_iterations=0, outputs={},
                      picture=None)
    acc = record["metrics"].get(spec["accuracy_key"])
    record["accuracy"] = -1.0 if acc is None or not np.isfinite(acc) else float(acc)
    # cpu_seconds: this process's CPU time during the target (all its threads); beside the
    # wall time it shows how much of a slow target was waiting for a core on a busy machine
    record.update(clock, seconds=time.perf_counter() - t0,
                  cpu_seconds=time.process_time() - cpu0, started=started, finished=time.time())
    write_json(dest / RESULT_FILE, {**record, "history": history})
    return record
