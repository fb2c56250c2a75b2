"""One thread policy: every component uses the cores this process may run on, or the override.

The thread count each component uses is read back from the component itself (the ray caster's
chunks, the width each module asks of the shared pool, BLAS through threadpoolctl, Open3D
through its own API), in this process and in a subprocess confined to one core by
``taskset -c 0``.
"""
import json
import os
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import geofit
from geofit import _threads

ROOT = Path(__file__).resolve().parents[1]

# Every module that runs work on geofit's pool, by component.
COMPONENTS = {
    "raycaster": "geofit.raycast.embree",
    "mesh": "geofit.render.mesh._raycast",
    "soft": "geofit.render.soft.fragments",
    "points": "geofit.render.points.rasterizer",
    "volume": "geofit.fit._volume_problem",
    "nerf": "geofit.fit._nerf_render",
}


def _workloads() -> dict:
    """Run each component once on a tiny input; return its thread-count attributes."""
    from geofit import FoVPerspectiveCameras, PointCloud, ico_sphere, look_at_view_transform
    from geofit.structures import MultiViewDataset
    from geofit.fit.nerf import render_nerf
    from geofit.fit.volume import VolumeFitOptions, fit_volume
    from geofit.render import (
        MeshRasterizer,
        PointsRasterizationSettings,
        PointsRasterizer,
        RasterizationSettings,
    )
    from geofit.render.volume.implicit import NeuralRadianceField
    from geofit.render.soft import SoftRasterizationSettings, rasterize_soft

    mesh = ico_sphere(2)
    rc = geofit.RayCaster(mesh)
    rng = np.random.default_rng(0)
    o = rng.normal(size=(60_000, 3)) * 3.0
    rc.cast(o, -o)
    R, T = look_at_view_transform(2.7, [0.0, 30.0], [0.0, 90.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    MeshRasterizer(cams, RasterizationSettings(image_size=32))(mesh)
    rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(16))
    cloud = PointCloud(rng.uniform(-0.5, 0.5, size=(60_000, 3)))
    PointsRasterizer(cams[0], PointsRasterizationSettings(image_size=32, radius=0.01))(cloud)
    images = np.full((2, 8, 8, 3), 0.5)
    sils = np.zeros((2, 8, 8))
    sils[:, 2:6, 2:6] = 1.0
    fit_volume(MultiViewDataset(images=images, silhouettes=sils, cameras=cams),
            options=VolumeFitOptions(volume_size=8, levels=(8,), iterations=1, n_pts_per_ray=16),
            progress=False)
    field = NeuralRadianceField(n_harmonic_functions=2, n_hidden_neurons=4,
                                n_harmonic_functions_dir=1, n_hidden_color=4, seed=0)
    pool_before = id(_threads._POOL)
    render_nerf(field, cams, 8, n_pts_per_ray=8)
    render_nerf(field, cams, 8, n_pts_per_ray=8)
    return {"raycaster_n_threads": rc.n_threads, "raycaster_chunks": len(rc._chunks(60_000)),
            "pool_reused": id(_threads._POOL) == pool_before}


def measure() -> dict:
    """Thread counts each component used, read back (also run in the ``taskset`` subprocess)."""
    import importlib

    seen: dict[str, list[int]] = {k: [] for k in COMPONENTS}
    patched = []
    for key, name in COMPONENTS.items():
        mod = importlib.import_module(name)
        orig = mod.parallel_map

        def record(fn, items, n_threads=None, _key=key, _orig=orig):
            seen[_key].append(_threads.get_num_threads() if n_threads is None
                              else int(n_threads))
            return _orig(fn, items, n_threads)

        mod.parallel_map = record
        patched.append((mod, orig))
    try:
        out = _workloads()
    finally:
        for mod, orig in patched:
            mod.parallel_map = orig
    out.update({k: max(v) if v else None for k, v in seen.items()})
    out.update({"cores": len(os.sched_getaffinity(0)), "num_threads": geofit.get_num_threads(),
                "blas": _threads.blas_threads(), "open3d": _threads.open3d_threads(),
                "pool": _threads.pool_size()})
    return out


def _assert_all(m: dict, n: int) -> None:
    assert m["num_threads"] == n
    for key in ("raycaster_n_threads", "raycaster_chunks", *COMPONENTS):
        assert m[key] == n, (key, m)
    assert m["blas"] and all(b == n for b in m["blas"]), m
    assert m["open3d"] == n, m
    assert m["pool"] == (n if n > 1 else 0), m  # one core: everything runs inline
    assert m["pool_reused"], m


def _run_measure(prefix=(), env=None) -> dict:
    """measure() in a new Python process (``prefix`` e.g. taskset), with ``env`` added."""
    code = ("import json, runpy; ns = runpy.run_path(%r); "
            "print('MEASURE', json.dumps(ns['measure']()))" % str(Path(__file__)))
    full_env = {k: v for k, v in os.environ.items() if k != _threads.ENV_VAR}
    full_env.update(PYTHONPATH=str(ROOT), **(env or {}))
    proc = subprocess.run([*prefix, sys.executable, "-c", code], capture_output=True, text=True,
                          env=full_env, cwd=str(ROOT), timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("MEASURE ")][-1]
    return json.loads(line[len("MEASURE "):])


@pytest.fixture
def clean_policy(monkeypatch):
    monkeypatch.delenv(_threads.ENV_VAR, raising=False)
    geofit.set_num_threads(None)
    yield
    monkeypatch.delenv(_threads.ENV_VAR, raising=False)
    geofit.set_num_threads(None)


def test_default_is_the_cpu_affinity(clean_policy):
    """Without an override every component uses the cores in this process's affinity."""
    n = len(os.sched_getaffinity(0))
    assert _threads.cpu_count() == n
    _assert_all(measure(), n)


@pytest.mark.slow
def test_one_core_under_taskset():
    """Under ``taskset -c 0`` (one allowed core) every component uses one thread."""
    if shutil.which("taskset") is None:
        pytest.skip("taskset is not installed")
    m = _run_measure(["taskset", "-c", "0"])
    assert m["cores"] == 1
    _assert_all(m, 1)


def test_set_num_threads_overrides_everything(clean_policy):
    """set_num_threads(1) reaches every component, BLAS and Open3D; None restores them."""
    n = len(os.sched_getaffinity(0))
    geofit.set_num_threads(1)
    m = measure()
    for key in ("raycaster_n_threads", "raycaster_chunks", *COMPONENTS):
        assert m[key] == 1, (key, m)
    assert m["blas"] and all(b == 1 for b in m["blas"])
    assert m["open3d"] == 1
    geofit.set_num_threads(None)
    assert geofit.get_num_threads() == n
    assert all(b == n for b in _threads.blas_threads())
    assert _threads.open3d_threads() == n


def test_environment_variable_overrides(clean_policy, monkeypatch):
    """GEOFIT_NUM_THREADS is read when asked; set_num_threads wins over it."""
    monkeypatch.setenv(_threads.ENV_VAR, "3")
    assert geofit.get_num_threads() == 3
    assert geofit.RayCaster(geofit.ico_sphere(1)).n_threads == 3
    geofit.set_num_threads(2)
    assert geofit.get_num_threads() == 2
    geofit.set_num_threads(None)
    assert geofit.get_num_threads() == 3


@pytest.mark.slow
def test_environment_variable_in_a_new_process():
    """GEOFIT_NUM_THREADS=1 set before import: every component, BLAS and Open3D use 1."""
    m = _run_measure(env={_threads.ENV_VAR: "1"})
    for key in ("num_threads", "raycaster_n_threads", "raycaster_chunks", *COMPONENTS):
        assert m[key] == 1, (key, m)
    assert all(b == 1 for b in m["blas"]) and m["open3d"] == 1


@pytest.mark.parametrize("bad", [0, -2, 1.5, "two", True])
def test_set_num_threads_validation(clean_policy, bad):
    with pytest.raises(ValueError, match="n: expected an integer >= 1"):
        geofit.set_num_threads(bad)


def test_environment_variable_validation(clean_policy, monkeypatch):
    monkeypatch.setenv(_threads.ENV_VAR, "zero")
    with pytest.raises(ValueError, match=_threads.ENV_VAR):
        geofit.get_num_threads()


def test_parallel_map_order_and_one_reused_pool(clean_policy):
    """Results keep their order; the pool is built once per thread count, never per call."""
    out = _threads.parallel_map(lambda a: a @ a.T, [np.eye(3) * i for i in range(4)], 2)
    assert [float(o[0, 0]) for o in out] == [0.0, 1.0, 4.0, 9.0]
    pool = _threads._POOL
    _threads.parallel_map(abs, range(-5, 5), 2)
    assert _threads._POOL is pool and _threads.pool_size() == 2
    _threads.parallel_map(abs, range(-5, 5), 3)
    assert _threads._POOL is not pool and _threads.pool_size() == 3
    assert _threads.parallel_map(abs, [-1], 3) == [1]


def test_nested_parallel_map_runs_inline():
    """A parallel_map inside a pool worker runs in that worker (no nested pools, no deadlock)."""
    def outer(i):
        return (_threads.in_worker(), _threads.parallel_map(lambda j: i * j, range(3), 2))

    out = _threads.parallel_map(outer, range(4), 2)
    assert [o[1] for o in out] == [[0, i, 2 * i] for i in range(4)]
    assert all(o[0] for o in out)
    assert not _threads.in_worker()


def test_one_blas_thread_restores_after_overlapping_threads(clean_policy):
    """A use from another thread inside a use from this one: the limit stays 1 until the
    outer use leaves, then the original limit is back."""
    before = _threads.blas_threads()
    seen = []

    def child():
        with _threads.one_blas_thread():
            seen.append(float((np.ones((64, 64)) @ np.ones((64, 64)))[0, 0]))

    with _threads.one_blas_thread():
        inside = _threads.blas_threads()
        t = threading.Thread(target=child)
        t.start()
        t.join()
        after_child = _threads.blas_threads()
    assert seen == [64.0]
    assert inside and all(b == 1 for b in inside) and after_child == inside
    assert _threads.blas_threads() == before


def test_one_openmp_thread_is_per_thread_and_restores():
    """Inside the block the calling thread's OpenMP runtimes report one thread, another thread
    keeps its own count, and the count is back after the block."""
    import threadpoolctl
    import pykdtree.kdtree  # noqa: F401  (loads an OpenMP runtime, libgomp)

    def omp(ctl=None):
        ctl = ctl or threadpoolctl.ThreadpoolController()
        return [lib.num_threads for lib in ctl.lib_controllers if lib.user_api == "openmp"]

    before = omp()
    assert before, "no OpenMP runtime loaded"
    other = []
    with _threads.one_openmp_thread():
        inside = omp()
        t = threading.Thread(target=lambda: other.append(omp()))
        t.start()
        t.join()
    assert inside == [1] * len(before)
    assert other == [before]  # OpenMP's count is per thread: the other thread is untouched
    assert omp() == before


# ------------------------------------------------------------------ one home per concept

_THREAD_RULES = [
    (re.compile(r"^\s*(import|from)\s+threadpoolctl\b", re.M), "imports threadpoolctl"),
    (re.compile(r"^\s*(import|from)\s+ctypes\b", re.M), "imports ctypes"),
    (re.compile(r"\bThreadPoolExecutor\b"), "uses ThreadPoolExecutor"),
    (re.compile(r"/proc/self/maps"), "reads /proc/self/maps"),
    (re.compile(r"sched_getaffinity"), "reads the CPU affinity"),
    (re.compile(r"os\.cpu_count\("), "reads the CPU count"),
    (re.compile(r"openblas", re.I), "talks to OpenBLAS"),
]
_EMBREE_RULES = [
    (re.compile(r"^\s*(import|from)\s+embreex\b|import_module\(\s*.embreex", re.M),
     "imports embreex"),
    (re.compile(r"\brtcore_scene\b|\bmesh_construction\b|\bTriangleMesh\(scene"),
     "builds an Embree scene"),
]


def _sources():
    for path in sorted((ROOT / "geofit").rglob("*.py")):
        yield path.relative_to(ROOT).as_posix(), path.read_text(encoding="utf-8")


def _code_only(text: str) -> str:
    """The source without docstrings and comments (mentions in prose are allowed)."""
    import io
    import tokenize

    out = []
    toks = tokenize.generate_tokens(io.StringIO(text).readline)
    prev = tokenize.INDENT
    for tok in toks:
        if tok.type == tokenize.COMMENT:
            continue
        if tok.type == tokenize.STRING and prev in (tokenize.INDENT, tokenize.NEWLINE,
                                                    tokenize.DEDENT, tokenize.NL):
            prev = tok.type
            continue  # a docstring
        out.append(tok.string if tok.type != tokenize.NEWLINE else "\n")
        if tok.type not in (tokenize.NL, tokenize.COMMENT):
            prev = tok.type
    return " ".join(out).replace(" \n ", "\n")


def test_only_threads_module_sets_threads_and_only_raycast_builds_embree_scenes():
    """No module but geofit/_threads.py touches thread counts, BLAS or pools; no module but
    geofit/raycast/embree.py imports embreex or builds an Embree scene."""
    bad = []
    for rel, text in _sources():
        code = _code_only(text)
        if rel != "geofit/_threads.py":
            bad += [f"{rel} {why}" for rx, why in _THREAD_RULES if rx.search(code)
                    # the machine description names the hardware's CPU count
                    and not (rel == "geofit/report.py" and why == "reads the CPU count")]
        if rel != "geofit/raycast/embree.py":
            bad += [f"{rel} {why}" for rx, why in _EMBREE_RULES if rx.search(code)]
    assert bad == []


def test_source_scan_catches_a_violation():
    """The scan itself fires on a second pool and on a second Embree scene."""
    sample = ("from concurrent.futures import ThreadPoolExecutor\nimport ctypes\n"
              "from embreex import rtcore_scene\n")
    code = _code_only(sample)
    assert sum(bool(rx.search(code)) for rx, _ in _THREAD_RULES) == 2
    assert sum(bool(rx.search(code)) for rx, _ in _EMBREE_RULES) == 2
    assert not any(rx.search(_code_only('"""uses ThreadPoolExecutor, embreex"""\nx = 1\n'))
                   for rx, _ in _THREAD_RULES + _EMBREE_RULES)


def test_docstring_examples_run(clean_policy):
    """The Examples of geofit._threads run (set_num_threads, then the default again)."""
    import doctest

    result = doctest.testmod(_threads, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0
