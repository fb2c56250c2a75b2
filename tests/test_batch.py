"""geofit.batch and `geofit batch`: Dask tasks per target on a LocalCluster and on a real
`dask scheduler` + `dask worker` cluster, failures, resumed batches, summary files, exit codes."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from geofit import ico_sphere, save_obj, torus
from geofit.batch import (
    ACCURACY,
    TASKS,
    BatchResult,
    expand_targets,
    fit_many,
    settings_hash,
    task_settings,
)
from geofit.batch._summary import SUMMARY_FILES
from geofit.batch._tasks import atomic_write, run_target
from geofit.cli import main

# The fit's defaults on small meshes, with a time budget far above what they need (a budget
# that binds would make the result depend on the machine's load).
FAST = {"time_budget": 120.0}
GOOD = ("sphere", "torus")


def _cores() -> int:
    return len(os.sched_getaffinity(0))


def _make_meshes(folder: Path, broken: bool = True) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    save_obj(folder / "sphere.obj", ico_sphere(1).scale_verts(1.5))
    save_obj(folder / "torus.obj", torus(major_radius=1.0, minor_radius=0.3, n_major=16, n_minor=8))
    if broken:  # a face that names a vertex the file does not have
        (folder / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n", encoding="utf-8")
    (folder / "notes.txt").write_text("not a mesh\n", encoding="utf-8")
    return folder


def _mtimes(out: Path) -> dict[str, int]:
    return {p.parent.name: p.stat().st_mtime_ns for p in out.glob("*/result.json")}


# ----------------------------------------------------------------------------- LocalCluster
@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """One batch over a folder with a broken file, on a LocalCluster of 2 worker processes."""
    base = tmp_path_factory.mktemp("batch")
    inputs = _make_meshes(base / "meshes")
    out = base / "out"
    workers = 2 if _cores() >= 2 else 1
    before = {c.pid for c in psutil.Process().children(recursive=True)}
    env = {k: os.environ.get(k) for k in THREAD_VARS}
    res = fit_many(inputs, "fit-mesh", out, n_workers=workers, progress=False, **FAST)
    assert {k: os.environ.get(k) for k in THREAD_VARS} == env  # this process's untouched
    return inputs, out, res, _mtimes(out), before


THREAD_VARS = ("GEOFIT_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
               "MKL_NUM_THREADS")


def _new_children(before: set[int], wait: float = 10.0) -> list[int]:
    """Child processes of this test process started since ``before`` and still running
    (except multiprocessing's resource tracker, which lives as long as this process)."""
    deadline = time.monotonic() + wait
    while True:
        alive = [c.pid for c in psutil.Process().children(recursive=True)
                 if c.pid not in before and c.status() != psutil.STATUS_ZOMBIE
                 and "resource_tracker" not in " ".join(c.cmdline())]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.2)


def test_local_cluster_fits_every_good_mesh(local_run):
    """2 worker processes: each good mesh gets status ok, a fitted mesh, metrics and history;
    the cluster's processes are gone afterwards."""
    _, out, res, _, before = local_run
    assert not _new_children(before), "LocalCluster processes left behind"
    assert isinstance(res, BatchResult) and [r.name for r in res] == ["broken", "sphere", "torus"]
    assert res.n_workers == min(2, _cores())
    for name in GOOD:
        row = next(r for r in res if r.name == name)
        assert row.ok and not row.reused and row.n_params > 0
        assert 0.0 <= row.accuracy <= 1.0 and row.seconds > row.fit_seconds > 0
        assert row.cpu_seconds > 0.0
        rec = json.loads((out / name / "result.json").read_text())
        assert rec["status"] == "ok" and rec["settings_hash"] == row.settings_hash
        assert rec["metrics"]["fscore@0.01"] == pytest.approx(row.accuracy)
        assert len(rec["history"]["loss"]) >= 1 and rec["history"]["n_params"][-1] == row.n_params
        assert (out / name / "fit.obj").stat().st_size > 0
        assert (out / name / "picture.png").stat().st_size > 0
        # the worker limited its threads (geofit.get_num_threads read back in the worker)
        assert rec["threads"] == _cores() // res.n_workers
        assert rec["warm"] is True  # the warm-up plugin ran on its worker before it
        # BLAS read back by threadpoolctl in the worker: the same count (not Dask's default 1)
        assert rec["blas_threads"] and set(rec["blas_threads"]) == {rec["threads"]}
    assert not list(out.rglob(".*tmp-*")), "temporary files left behind"
    assert set(res.timings) == {"cluster_start", "warm_up", "tasks", "tear_down", "summary"}
    assert all(v >= 0.0 for v in res.timings.values())
    assert sum(res.timings.values()) <= res.seconds


def test_largest_input_first(local_run, tmp_path):
    """Targets are submitted largest input first: the 2 workers start the torus and the
    sphere, the tiny broken file waits for a free worker (name order would start it first)."""
    inputs, out, _, _, _ = local_run
    started = {n: json.loads((out / n / "result.json").read_text())["started"]
               for n in ("broken", *GOOD)}
    if _cores() >= 2:
        assert started["broken"] > max(started[n] for n in GOOD)
    from geofit.batch import input_bytes, largest_first

    sizes = {p.stem: input_bytes(p) for p in inputs.glob("*.obj")}
    assert sizes["torus"] > sizes["sphere"] > sizes["broken"] > 0
    specs = [{"path": str(inputs / f"{n}.obj"), "name": n} for n in ("broken", "sphere", "torus")]
    assert [s["name"] for s in largest_first(specs)] == ["torus", "sphere", "broken"]
    cap = _capture(tmp_path / "cap")  # a folder: the bytes of every file in it
    assert input_bytes(cap) == sum(p.stat().st_size for p in cap.rglob("*") if p.is_file())


def test_broken_input_recorded_as_failed(local_run):
    """The broken file fails with its error type and message; the batch went on."""
    _, out, res, _, _ = local_run
    row = res[0]
    assert row.status == "failed" and row.error_type == "ValueError"
    assert "out of range" in row.message and row.accuracy == -1.0
    rec = json.loads((out / "broken" / "result.json").read_text())
    assert rec["status"] == "failed" and rec["error"]["type"] == "ValueError"
    assert "broken.obj" in rec["error"]["message"]
    assert res.n_failed == 1 and res.exit_code == 1


def test_summary_files_written(local_run):
    _, out, res, _, _ = local_run
    for f in SUMMARY_FILES:
        assert (out / f).stat().st_size > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_ok"] == 2 and summary["n_failed"] == 1
    lines = (out / "summary.csv").read_text().splitlines()
    assert lines[0].startswith("name,target,task,status") and len(lines) == 4
    html = (out / "index.html").read_text()
    assert 'src="sphere/picture.png"' in html and 'href="torus/fit.obj"' in html
    assert "broken" in html and res[1].outputs == {"mesh": "sphere/fit.obj"}


def test_rerun_skips_finished_targets(local_run):
    """Same settings: nothing is recomputed and no cluster is started (result.json files
    untouched); retry_failed recomputes only the failed target; a changed setting changes the
    hash."""
    inputs, out, first, mtimes, _ = local_run
    res = fit_many(inputs, "fit-mesh", out, n_workers=1, progress=False, **FAST)
    assert res.n_reused == 3 and res.n_workers == 0 and _mtimes(out) == mtimes
    # the page names the workers that computed the results, not "0 workers"
    html = (out / "index.html").read_text()
    assert "0 worker(s)" not in html
    assert f"computed by {min(2, _cores())} worker process(es)" in html
    assert [r.status for r in res] == [r.status for r in first]
    assert [r.accuracy for r in res] == [r.accuracy for r in first]
    res = fit_many(inputs, "fit-mesh", out, n_workers=1, progress=False, retry_failed=True,
                   summary=False, **FAST)
    after = _mtimes(out)
    assert not res[0].reused and res[0].status == "failed" and after["broken"] > mtimes["broken"]
    assert res.n_workers == 1 and all(after[n] == mtimes[n] for n in GOOD)
    # 1 worker x all cores: its BLAS got them too (a Dask nanny would have set 1)
    rec = json.loads((out / "broken" / "result.json").read_text())
    assert rec["threads"] == _cores() and set(rec["blas_threads"]) == {_cores()}
    assert settings_hash("fit-mesh", inputs / "torus.obj", task_settings("fit-mesh", **FAST)) \
        != settings_hash("fit-mesh", inputs / "torus.obj",
                         task_settings("fit-mesh", **{**FAST, "seed": 1}))


# ----------------------------------------------------------------------------- real cluster
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args: str) -> list[str]:
    return [sys.executable, "-m", "distributed.cli.dask_" + args[0], *args[1:]]


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """`dask scheduler` and two `dask worker` processes on 127.0.0.1, torn down afterwards."""
    from distributed import Client

    from geofit.batch import thread_env

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    scratch = tmp_path_factory.mktemp("dask")
    import geofit

    # the processes start in scratch: they import this checkout's geofit by absolute path
    root = str(Path(geofit.__file__).resolve().parents[1])
    path = os.pathsep.join([root] + [q for q in os.environ.get("PYTHONPATH", "").split(
        os.pathsep) if q])
    env = {**os.environ, **thread_env(1),  # as docs/batch.md starts them
           "DASK_DISTRIBUTED__SCHEDULER__WORKER_SATURATION": "1.0", "PYTHONPATH": path}
    log = open(scratch / "dask.log", "wb")  # noqa: SIM115 - closed in the finally below
    procs: list[subprocess.Popen] = []
    try:
        procs.append(subprocess.Popen(
            _dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard",
                  "--dashboard-address", "127.0.0.1:0"),
            cwd=scratch, env=env, stdout=log, stderr=subprocess.STDOUT))
        for _ in range(2):
            procs.append(subprocess.Popen(
                _dask("worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                      "--nworkers", "1", "--no-dashboard", "--local-directory", str(scratch)),
                cwd=scratch, env=env, stdout=log, stderr=subprocess.STDOUT))
        with Client(address, timeout=30) as c:
            c.wait_for_workers(2, timeout=60)
        tree = {p.pid for p in procs}
        for p in procs:
            tree |= {c.pid for c in psutil.Process(p.pid).children(recursive=True)}
        yield address
        for p in procs:  # the nannies' worker processes too
            tree |= {c.pid for c in psutil.Process(p.pid).children(recursive=True)}
        with Client(address, timeout=30) as c:
            c.shutdown()  # scheduler and workers close themselves
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:  # pragma: no cover - a hung process
                p.kill()
                p.wait()
        log.close()
    deadline = time.monotonic() + 10
    alive = [pid for pid in tree if psutil.pid_exists(pid)]
    while alive and time.monotonic() < deadline:
        time.sleep(0.2)
        alive = [pid for pid in alive if psutil.pid_exists(pid)
                 and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE]
    assert not alive, f"dask processes left behind: {alive}"


def test_cli_on_dask_scheduler_and_workers_exit_codes(dask_cluster, tmp_path, capsys):
    """`geofit batch fit-mesh DIR --scheduler ADDRESS` runs on the external workers: exit 1
    with a broken file (the good ones succeed), 0 for a folder of good meshes."""
    inputs = _make_meshes(tmp_path / "meshes")
    flags = ["--time-budget", "120", "--scheduler", dask_cluster, "--no-progress"]
    code = main(["batch", "fit-mesh", str(inputs), "--out", str(tmp_path / "o1"), *flags])
    assert code == 1
    summary = json.loads((tmp_path / "o1" / "summary.json").read_text())
    assert summary["scheduler"] == dask_cluster and summary["n_workers"] == 2
    assert {t["name"]: t["status"] for t in summary["targets"]} == {
        "broken": "failed", "sphere": "ok", "torus": "ok"}
    recs = [json.loads((tmp_path / "o1" / n / "result.json").read_text()) for n in GOOD]
    assert os.getpid() not in {r["pid"] for r in recs}  # computed by the workers, not here
    # 2 single-slot workers on this host share its cores
    assert all(r["threads"] == max(1, _cores() // 2) for r in recs)
    assert all(r["warm"] for r in recs)  # the plugin reached the external workers too
    good = _make_meshes(tmp_path / "good", broken=False)
    code = main(["batch", "fit-mesh", str(good / "sphere.obj"), str(good / "torus.obj"),
                 "--out", str(tmp_path / "o2"), *flags])
    assert code == 0
    assert "2 targets: 2 ok, 0 failed" in capsys.readouterr().out


# ----------------------------------------------------------------------------- the tasks
@pytest.mark.parametrize("task, kw", [
    ("render", {"views": 2, "image_size": 32}),
    # fit-views: its default (no budget) is a few seconds at this size; the others get budgets
    # far above their set-up, so that the first step happens even on a loaded machine
    ("fit-views", {"views": 4, "image_size": 16, "heldout": 2}),
    ("fit-volume", {"views": 4, "image_size": 16, "heldout": 2, "time_budget": 15.0}),
    ("fit-nerf", {"views": 4, "image_size": 16, "heldout": 2, "time_budget": 5.0}),
])
def test_task_on_a_mesh_file(task, kw, tmp_path):
    """Every task runs on a mesh file (the multi-view tasks on renders of it) and writes its
    result, outputs and picture; the headline metric is in range."""
    path = tmp_path / "sphere.obj"
    save_obj(path, ico_sphere(2))
    s = task_settings(task, **kw)
    rec = run_target({"task": task, "path": str(path), "name": "sphere", "out": str(tmp_path),
                      "settings": s, "settings_hash": settings_hash(task, path, s),
                      "threads": 1, "accuracy_key": ACCURACY[task][0]})
    assert rec["status"] == "ok", rec["message"]
    for f in rec["outputs"].values():
        assert (tmp_path / "sphere" / f).stat().st_size > 0
    assert (tmp_path / "sphere" / "picture.png").exists()
    key = ACCURACY[task][0]
    lo, hi = (0.0, 1.0) if key != "psnr" else (5.0, 100.0)
    assert lo < rec["accuracy"] <= hi and rec["accuracy"] == rec["metrics"][key]


def _capture(folder: Path, fmt: str = "transforms") -> Path:
    """A capture written by geofit.io.save_views from renders of a coloured sphere."""
    from geofit.batch._tasks import _coloured
    from geofit.datasets import render_views
    from geofit.io import save_views

    views = render_views(_coloured(ico_sphere(2)), np.linspace(0.0, 360.0, 9)[:-1], 10.0,
                         image_size=24)
    save_views(folder, views, format=fmt)
    return folder


def test_capture_folder_through_load_views(tmp_path):
    """fit-volume and fit-views on capture folders (transforms.json, COLMAP) found in a folder
    next to a mesh file: read by geofit.io.load_views, every 8th view held out."""
    _capture(tmp_path / "scans" / "a")
    _capture(tmp_path / "scans" / "b", "colmap")
    save_obj(tmp_path / "scans" / "m.obj", ico_sphere(1))
    assert [n for n, _ in expand_targets(tmp_path / "scans", "fit-volume")] == ["a", "b", "m"]
    assert [n for n, _ in expand_targets(tmp_path / "scans", "fit-mesh")] == ["m"]
    for task, name, kw in (("fit-volume", "a", {"time_budget": 15.0}), ("fit-views", "b", {})):
        s = task_settings(task, **kw)
        rec = run_target({"task": task, "path": str(tmp_path / "scans" / name), "name": name,
                          "out": str(tmp_path / "o"), "settings": s, "settings_hash": "h",
                          "threads": 1, "accuracy_key": ACCURACY[task][0]})
        assert rec["status"] == "ok", rec["message"]
        assert 0.0 < rec["accuracy"] and (tmp_path / "o" / name / "picture.png").exists()


def test_broken_capture_recorded_as_failed(tmp_path):
    """A capture whose transforms.json has no frames fails with load_views' ValueError."""
    cap = tmp_path / "scan"
    cap.mkdir()
    (cap / "transforms.json").write_text("{}", encoding="utf-8")
    assert expand_targets(tmp_path, "fit-volume") == [("scan", cap.resolve())]
    s = task_settings("fit-volume")
    rec = run_target({"task": "fit-volume", "path": str(cap), "name": "scan",
                      "out": str(tmp_path / "o"), "settings": s, "settings_hash": "h",
                      "threads": 1, "accuracy_key": "psnr"})
    assert rec["status"] == "failed" and rec["error"]["type"] == "ValueError"
    assert "transforms.json" in rec["error"]["message"]


# ----------------------------------------------------------------------------- helpers
def test_expand_targets_names_and_order(tmp_path):
    """Folders expand to mesh files in name order; equal stems get distinct names."""
    _make_meshes(tmp_path / "a", broken=False)
    _make_meshes(tmp_path / "b", broken=False)
    items = expand_targets([tmp_path / "a", tmp_path / "b" / "torus.obj",
                            tmp_path / "a" / "sphere.obj"])
    names = [n for n, _ in items]
    assert len(items) == 3 and len(set(names)) == 3
    assert names[0] == "sphere" and all(n.startswith("torus-") for n in names[1:])


def test_settings_hash_follows_the_input_file(tmp_path):
    p = tmp_path / "m.obj"
    save_obj(p, ico_sphere(1))
    s = task_settings("fit-mesh")
    h = settings_hash("fit-mesh", p, s)
    assert h == settings_hash("fit-mesh", p, s)
    save_obj(p, ico_sphere(2))
    assert settings_hash("fit-mesh", p, s) != h


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "x.json"
    target.write_text("old")

    def bad(p):
        p.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(target, bad)
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]


def test_thread_env_names_geofit_openmp_and_blas():
    """The worker environment gives geofit, OpenMP and BLAS the same count; a bad count is
    refused by geofit's thread policy."""
    from geofit.batch import thread_env

    env = thread_env(3)
    assert set(env) == set(THREAD_VARS) and set(env.values()) == {"3"}
    with pytest.raises(ValueError, match="n: expected an integer >= 1"):
        thread_env(0)


def test_every_task_has_options_and_an_accuracy():
    assert set(TASKS) == set(ACCURACY) == {"fit-mesh", "render", "fit-views", "fit-volume",
                                           "fit-nerf"}


@pytest.mark.parametrize("kw, match", [
    ({"task": "fit-everything"}, "task"),
    ({"time_budget": -1.0}, "time_budget"),
    ({"recipe": "magic"}, "recipe"),
    ({"learning_rate": 0.1}, "learning_rate"),
    ({"n_workers": 0}, "n_workers"),
    ({"threads_per_worker": 1.5, "scheduler": "tcp://127.0.0.1:1"}, "threads_per_worker"),
    ({"n_workers": 1, "threads_per_worker": 1024}, "exceeds"),
    ({"client": object(), "scheduler": "tcp://127.0.0.1:1"}, "client, scheduler"),
])
def test_fit_many_validation(kw, match, tmp_path):
    _make_meshes(tmp_path / "m", broken=False)
    with pytest.raises(ValueError, match=match):
        fit_many(tmp_path / "m", out=tmp_path / "o", progress=False, **kw)


def test_fit_many_option_of_the_wrong_type(tmp_path):
    _make_meshes(tmp_path / "m", broken=False)
    with pytest.raises(TypeError, match="time_budget: expected float"):
        fit_many(tmp_path / "m", out=tmp_path / "o", time_budget="5")


def test_fit_many_missing_or_empty_targets(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing"):
        fit_many(tmp_path / "nothing", out=tmp_path / "o")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no mesh files"):
        fit_many(tmp_path / "empty", out=tmp_path / "o")


def test_cli_help_documents_exit_codes(capsys):
    with pytest.raises(SystemExit):
        main(["batch", "fit-mesh", "--help"])
    text = capsys.readouterr().out
    assert "--scheduler" in text and "--time-budget" in text and "--recipe" in text
    assert "1  at least one target failed" in text


def test_docs_batch_commands_parse():
    """The batch guide's commands (docs/batch.md) use only flags that exist: geofit's parse,
    dask's are in its --help."""
    import re
    import shlex

    from geofit.cli import build_parser

    section = (Path(__file__).resolve().parents[1] / "docs" / "batch.md").read_text(encoding="utf-8")
    lines = [ln.rstrip(" &") for ln in re.findall(r"^(?:\S+=\S+ )*(?:geofit|dask) .*$", section,
                                                  flags=re.MULTILINE)]
    geofit_lines = [ln for ln in lines if ln.startswith("geofit batch")]
    dask_lines = [ln for ln in lines if "dask " in ln]
    assert len(geofit_lines) == 2 and len(dask_lines) == 2
    for ln in geofit_lines:
        args = build_parser().parse_args(shlex.split(ln)[1:])
        assert args.task == "fit-mesh" and args.time_budget == 5.0
    import importlib

    for ln in dask_lines:
        words = shlex.split(ln)
        words = words[next(i for i, w in enumerate(words) if w == "dask"):]
        command = importlib.import_module(f"distributed.cli.dask_{words[1]}").main  # click
        flags = {o for p in command.params for o in p.opts + p.secondary_opts}
        for flag in (w for w in words if w.startswith("--")):
            assert flag in flags, f"{flag} is not a flag of dask {words[1]}"
