"""What one Dask task does: load its own input, fit or render, write its outputs atomically.

Runs in a worker process. Everything here receives plain data (paths, dicts of settings) and
builds its own objects, so no Embree scene, Open3D object or big array crosses a process
boundary. Each task has ONE adapter function calling the geofit workflow (``_fit_mesh_call``,
``_fit_views_call``, ``_fit_volume_call``, ``_fit_nerf_call``, ``_load_capture``): when a
workflow's signature changes, one line changes here.
"""
from __future__ import annotations

import json
import os
import socket
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_write as _atomic_write

RESULT_SCHEMA = "geofit-batch-result/1"
RESULT_FILE = "result.json"
PICTURE_FILE = "picture.png"

#: Suffixes of the mesh files a folder target expands to.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

#: Files whose presence makes a folder a multi-view capture (the layouts
#: ``geofit.datasets.load_views`` reads): the NeRF/Blender ``transforms.json``, a COLMAP text
#: model (also under ``sparse/0``), OpenCV K/R/t per view in ``cameras.json``.
CAPTURE_MARKERS = ("transforms.json", "cameras.txt", "sparse/0/cameras.txt",
                   "sparse/cameras.txt", "cameras.json")

#: Held-out share of a capture without a split of its own: every ``HOLDOUT_EVERY``-th view.
HOLDOUT_EVERY = 8


def is_capture(path: Path) -> bool:
    """True for a folder holding a multi-view capture (one of :data:`CAPTURE_MARKERS`)."""
    return path.is_dir() and any((path / m).is_file() for m in CAPTURE_MARKERS)


# ------------------------------------------------------------------------------ small helpers
def atomic_write(path: Path, write: Callable[[Path], Any]) -> Path:
    """``write(tmp)`` to a temporary file beside ``path``, then ``os.replace`` it into place.

    The temporary name keeps the suffix (writers choose the format by it); a reader never sees
    a half-written file, and a crash leaves at most a hidden ``.*.tmp-*`` file.
    """
    return _atomic_write(path, write)  # the one atomic, durable write (fsync too)


def write_json(path: Path, data: dict) -> Path:
    """Write ``data`` as indented JSON, atomically (non-finite floats as strings)."""
    from ..fit.history import _json_safe

    text = json.dumps(_json_safe(data), indent=1) + "\n"
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def _save_png(path: Path, image: np.ndarray) -> Path:
    from PIL import Image

    arr = (np.clip(np.asarray(image, np.float64), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return atomic_write(path, lambda p: Image.fromarray(arr).save(p))


def _save_mesh(path: Path, mesh) -> Path:
    from ..io import save_obj
    from ..structures import Mesh

    plain = Mesh(mesh.verts, mesh.faces)
    return atomic_write(path, lambda p: save_obj(p, plain))


def _save_npz(path: Path, **arrays) -> Path:
    return atomic_write(path, lambda p: np.savez_compressed(p, **arrays))


def _rows(*rows: np.ndarray) -> np.ndarray:
    """Stack rows of (n, H, W, 3) images into one picture (each row tiled left to right)."""
    return np.concatenate([np.concatenate(list(r[..., :3]), axis=1) for r in rows], axis=0)


def limit_threads(n: int) -> int:
    """Limit this worker's compute threads to ``n``: ``geofit.set_num_threads`` when geofit
    has it (geofit's pool for ray casting and rendering, BLAS through threadpoolctl, Open3D),
    and ``GEOFIT_NUM_THREADS`` / ``OMP_NUM_THREADS`` for anything that reads them later.
    Returns the count geofit reports back (``geofit.get_num_threads()``), else ``n``."""
    import geofit

    os.environ["GEOFIT_NUM_THREADS"] = str(n)
    os.environ["OMP_NUM_THREADS"] = str(n)
    setter = getattr(geofit, "set_num_threads", None)
    if setter is not None:
        setter(n)
    getter = getattr(geofit, "get_num_threads", None)
    return int(getter()) if getter is not None else n


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
    import importlib

    from .._threads import blas_threads

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
    from ..io import load_mesh

    mesh = load_mesh(path, load_textures=textures) if path.suffix.lower() == ".obj" \
        else load_mesh(path)
    if mesh.n_faces == 0:
        raise ValueError(f"{path}: the mesh has no faces")
    return mesh


def _coloured(mesh):
    """The mesh normalised (as the tutorials), with vertex colours from its normals when it has
    no texture, so that RGB renders carry information."""
    from ..structures import Mesh, TexturesVertex

    m = mesh.normalize().mesh
    if m.textures is None:
        m = Mesh(m.verts, m.faces, TexturesVertex(0.25 + 0.5 * np.abs(m.verts_normals)))
    return m


def _load_capture(folder: Path, background: tuple):
    """A capture folder -> (images (N, H, W, 3), silhouettes (N, H, W), cameras), RGBA images
    composited over ``background`` (black for the volume and NeRF fits, white for the mesh).

    The one place that knows ``geofit.datasets.load_views``' contract (a dataset with
    ``images``, ``silhouettes`` and ``cameras``).
    """
    from ..datasets import load_views

    ds = load_views(folder, background=background)
    return (np.asarray(ds.images, np.float64)[..., :3], np.asarray(ds.silhouettes, np.float64),
            ds.cameras)


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
    return ((images[tr], silhouettes[tr], cameras[tr]),
            (images[te], silhouettes[te], cameras[te]))


def _tutorial5_views(path: Path, s: dict):
    """Training and held-out (images, silhouettes, cameras) for fit-volume / fit-nerf: a
    capture folder, or renders of a mesh file as the tutorial renders the cow (azimuths around
    it at elevation 0, black background; held out: the azimuths half-way, elevation 20)."""
    if path.is_dir():
        return _split(*_load_capture(path, (0.0, 0.0, 0.0))) + (None,)
    from ..datasets import render_views, training_azimuths

    mesh = _coloured(_load_mesh(path, textures=True))
    az = training_azimuths(s["views"])
    train = render_views(mesh, az, 0.0, image_size=s["image_size"])
    step = 360.0 / s["views"]
    az_h = (az[: max(1, min(s["heldout"], s["views"]))] + step / 2.0)
    test = render_views(mesh, az_h, 20.0, image_size=s["image_size"])
    return ((train.images, train.silhouettes, train.cameras),
            (test.images, test.silhouettes, test.cameras), mesh)


# ------------------------------------------------------------------------------ adapters
def _fit_mesh_call(target, **kwargs):
    """geofit's mesh fit with its default start."""
    from ..fit import fit_mesh

    return fit_mesh(target, **kwargs)


def _fit_views_call(train, **kwargs):
    """geofit's mesh-from-views fit (tutorial 4) with its defaults."""
    from ..fit.views import fit_mesh_to_views

    return fit_mesh_to_views(train, progress=False, **kwargs)


def _fit_volume_call(images, silhouettes, cameras, **kwargs):
    """geofit's volume fit (tutorial 5) with its defaults."""
    from ..datasets import MultiViewDataset
    from ..fit.volume import fit_volume

    return fit_volume(MultiViewDataset(images=images, silhouettes=silhouettes, cameras=cameras),
                      progress=False, **kwargs)


def _fit_nerf_call(images, silhouettes, cameras, **kwargs):
    """geofit's NeRF fit (tutorial 6) with its defaults."""
    from ..datasets import MultiViewDataset
    from ..fit.nerf import fit_nerf

    return fit_nerf(MultiViewDataset(images=images, silhouettes=silhouettes, cameras=cameras),
                    progress=False, **kwargs)


def _given(s: dict, mapping: dict) -> dict:
    """``{kwarg: s[option]}`` for the options in ``mapping`` that are set (not None)."""
    return {kw: s[opt] for opt, kw in mapping.items() if s.get(opt) is not None}


def _task_fit_mesh(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    from ..metrics import MeshEvaluator

    t = time.perf_counter()
    target = _load_mesh(path)
    clock["load_seconds"] = time.perf_counter() - t
    kw = {"recipe": s["recipe"]} if s.get("recipe") else {}
    kw.update(_given(s, {"time_budget": "time_budget", "n_iter": "n_iter"}))
    res = _fit_mesh_call(target, seed=s["seed"], evaluator=None, progress=False, **kw)
    clock["fit_seconds"] = res.seconds
    t = time.perf_counter()
    m = MeshEvaluator(target, n_samples=s["metric_samples"], taus=(0.01,), normalize=True,
                      seed=0).evaluate(res.mesh)
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
    from ..structures import Mesh

    norm = target.normalize()
    fit_n = Mesh((fitted.verts - norm.center) / norm.scale, fitted.faces)
    return _rows(_views(norm.mesh, 3, size), _views(fit_n, 3, size))


def _views(mesh, n: int, size: int, *, dist: float = 2.7, elev: float = 20.0):
    """``n`` Phong renders (n, size, size, 4) of ``mesh`` at azimuths spread around it."""
    from ..cameras import FoVPerspectiveCameras, look_at_view_transform
    from ..render import (
        HardPhongShader,
        MeshRasterizer,
        MeshRenderer,
        PointLights,
        RasterizationSettings,
    )

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
    from ..datasets import MultiViewDataset, tutorial_views
    from ..fit._views_objective import dataset_lights
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
    kw = _given(s, {"time_budget": "silhouette_time", "iterations": "silhouette_iters"})
    fit = _fit_views_call(train, seed=s["seed"], **kw)
    clock["fit_seconds"] = fit.seconds
    t = time.perf_counter()
    colors = fit.colors if fit.colors is not None else np.full((fit.mesh.n_verts, 3), 0.7)
    metrics = ViewsEvaluator(heldout, truth, n_samples=s["metric_samples"], taus=(0.01,))(
        fit.mesh, colors)
    clock["eval_seconds"] = time.perf_counter() - t
    _save_mesh(dest / "fit.obj", fit.mesh)
    _save_npz(dest / "fit_colors.npz", verts=fit.mesh.verts, faces=fit.mesh.faces,
              colors=colors)
    from ..render import MeshRasterizer, MeshRenderer, RasterizationSettings, SoftPhongShader
    from ..structures import Mesh, TexturesVertex

    k = min(4, len(heldout))
    cams = heldout.cameras[np.arange(k)]
    ras = MeshRasterizer(cams, RasterizationSettings(image_size=heldout.image_size))
    tm = Mesh(fit.mesh.verts, fit.mesh.faces, TexturesVertex(np.clip(colors, 0, 1)))
    shader = SoftPhongShader(cameras=cams, lights=dataset_lights(heldout))
    pred = np.asarray(MeshRenderer(ras, shader)(tm), np.float64)
    target_rgb = heldout.images[:k] if heldout.images is not None else \
        np.repeat(heldout.silhouettes[:k, ..., None], 3, axis=-1)
    _save_png(dest / PICTURE_FILE, _rows(target_rgb, pred))
    return {"fit": fit, "metrics": metrics,
            "outputs": {"mesh": "fit.obj", "colors": "fit_colors.npz"},
            "extra": {"n_verts": fit.mesh.n_verts, "stages": fit.stages}}


def _task_fit_volume(path: Path, dest: Path, s: dict, clock: dict) -> dict:
    from ..fit.volume import volume_metrics

    t = time.perf_counter()
    (tr, te, _) = _tutorial5_views(path, s)
    clock["load_seconds"] = time.perf_counter() - t
    kw = _given(s, {"time_budget": "time_budget", "size": "volume_size", "method": "method"})
    res = _fit_volume_call(*tr, seed=s["seed"], **kw)
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
    from dataclasses import asdict

    t = time.perf_counter()
    (tr, te, _) = _tutorial5_views(path, s)
    clock["load_seconds"] = time.perf_counter() - t
    kw = _given(s, {"time_budget": "time_budget", "recipe": "recipe", "n_iter": "n_iter"})
    res = _fit_nerf_call(*tr, held_out=te, seed=s["seed"], **kw)
    clock["fit_seconds"] = res.seconds
    _save_npz(dest / "nerf_field.npz", **res.field.params, config=json.dumps(asdict(res.config)))
    if res.images is not None:
        k = min(4, len(te[0]))
        _save_png(dest / PICTURE_FILE, _rows(te[0][:k], np.asarray(res.images)[:k]))
    psnr = -1.0 if res.psnr is None else float(res.psnr)
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
        ok = fit is None or fit.ok
        record.update(
            status="ok" if ok else "failed",
            message="" if fit is None else f"{fit.status}: {fit.message}",
            error=None if ok else {"type": "FitStatus", "message": f"the fit ended with status "
                                                                  f"{fit.status!r}"},
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
