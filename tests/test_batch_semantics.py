"""What a batch target's status means, what a rerun redoes, which output folders are refused, and
a clean end when Dask's shutdown goes wrong."""
from __future__ import annotations

import errno
import json
import os
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import psutil
import pytest

from geofit import ico_sphere, save_obj, torus
from geofit.batch import _previous, fit_many, settings_hash, task_settings
from geofit.batch import _tasks
from geofit.batch._tasks import run_target, verdict


def _mesh(folder: Path, name: str = "torus") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.obj"
    save_obj(path, torus(major_radius=1.0, minor_radius=0.3, n_major=16, n_minor=8))
    return path


def _spec(path: Path, out: Path, task: str = "fit-mesh", **kw) -> dict:
    s = task_settings(task, **kw)
    return {"task": task, "path": str(path), "name": path.stem, "out": str(out), "settings": s,
            "settings_hash": settings_hash(task, path, s), "threads": 1,
            "accuracy_key": "fscore@0.01"}


# ----------------------------------------------------------------------------- "ok" means done
def test_budget_cut_before_the_first_step_is_a_failure(tmp_path):
    """A fit whose time budget ran out before its first step returns its start: the target
    fails with that reason (it used to be recorded "ok")."""
    rec = run_target(_spec(_mesh(tmp_path / "in"), tmp_path / "out", time_budget=1e-9))
    assert rec["status"] == "failed" and rec["n_iterations"] == 0
    assert rec["error"]["type"] == "NoProgress" and rec["cause"] == "target"
    assert "time budget of 1e-09 s ran out before its first step" in rec["message"]
    on_disk = json.loads((tmp_path / "out" / "torus" / "result.json").read_text())
    assert on_disk["status"] == "failed" and on_disk["error"]["type"] == "NoProgress"


def _fit(status="converged", steps=3, ok=True, **extra):
    return SimpleNamespace(status=status, message="m", n_iterations=steps, ok=ok, **extra)


@pytest.mark.parametrize("fit, accuracy, kind", [
    (_fit(), 0.9, None),
    (None, 0.5, None),                                       # a render: no fit
    (_fit(steps=0, status="max_iter"), 0.9, "NoProgress"),
    (_fit(steps=0, status="time_budget"), 0.9, "NoProgress"),
    (_fit(status="nonfinite", ok=False), 0.9, "FitStatus"),
    (_fit(accepted=False), 0.9, "FitStatus"),                # the fit's own acceptance
    (_fit(), float("nan"), "FitStatus"),
])
def test_verdict(fit, accuracy, kind):
    """ok needs: the fit ended well by its own account, >= 1 step, a finite accuracy."""
    got = verdict(fit, accuracy, {"time_budget": 2.0})
    assert (got is None) if kind is None else got["type"] == kind


# ----------------------------------------------------------------------------- reruns
@pytest.mark.parametrize("exc, cause", [
    (OSError(errno.ENOSPC, "No space left on device"), "environment"),
    (MemoryError("out of memory"), "environment"),
    (ValueError("bad face index"), "target"),
])
def test_failure_cause_decides_the_rerun(exc, cause, tmp_path, monkeypatch):
    """A failure caused by the machine (disk full, memory) is redone by a plain rerun; one
    caused by the target is kept until retry_failed."""
    def boom(path, dest, s, clock):
        raise exc

    monkeypatch.setitem(_tasks.ADAPTERS, "fit-mesh", boom)
    spec = _spec(_mesh(tmp_path / "in"), tmp_path / "out")
    rec = run_target(spec)
    assert rec["status"] == "failed" and rec["cause"] == cause
    dest = tmp_path / "out" / "torus"
    kept = _previous(dest, spec["settings_hash"], retry_failed=False)
    assert (kept is None) == (cause == "environment")
    assert _previous(dest, spec["settings_hash"], retry_failed=True) is None


def test_rerun_redoes_an_environment_failure(tmp_path, monkeypatch):
    """End to end on an in-process cluster: a target that failed with a full disk is redone
    by the next plain run (and succeeds), the summary is written both times."""
    from distributed import Client, LocalCluster

    from geofit.batch import LOCAL_CLUSTER

    _mesh(tmp_path / "in")
    real = _tasks.ADAPTERS["fit-mesh"]

    def disk_full(path, dest, s, clock):
        raise OSError(errno.ENOSPC, "No space left on device")

    # in-process (no socket; the patched task reaches the worker thread)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      **LOCAL_CLUSTER) as cluster, \
            Client(cluster) as client:
        monkeypatch.setitem(_tasks.ADAPTERS, "fit-mesh", disk_full)
        first = fit_many(tmp_path / "in", out=tmp_path / "out", client=client, progress=False,
                         time_budget=120.0)
        assert first.n_failed == 1 and first[0].cause == "environment"
        assert json.loads((tmp_path / "out" / "summary.json").read_text())["n_failed"] == 1
        monkeypatch.setitem(_tasks.ADAPTERS, "fit-mesh", real)
        again = fit_many(tmp_path / "in", out=tmp_path / "out", client=client, progress=False,
                         time_budget=120.0)
    assert not again[0].reused and again[0].ok and again.exit_code == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["n_ok"] == 1


# ----------------------------------------------------------------------------- output folder
def test_out_that_is_a_file_is_refused_before_the_first_task(tmp_path):
    _mesh(tmp_path / "in")
    (tmp_path / "taken").write_text("x")
    before = {c.pid for c in psutil.Process().children(recursive=True)}
    with pytest.raises(ValueError, match=r"^out: .*taken is a file; expected a folder"):
        fit_many(tmp_path / "in", out=tmp_path / "taken", progress=False)
    assert {c.pid for c in psutil.Process().children(recursive=True)} <= before  # no cluster
    assert (tmp_path / "taken").read_text() == "x"


def test_read_only_out_is_refused_before_the_first_task(tmp_path):
    """(Root ignores permission bits: as root, sysfs stands in for a read-only folder.)"""
    _mesh(tmp_path / "in")
    if os.geteuid() == 0:
        ro = Path("/sys")
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
    with pytest.raises(ValueError, match=r"^out: the folder .* is not writable") as info:
        fit_many(tmp_path / "in", out=ro, progress=False)
    assert "\n" not in str(info.value)


# ----------------------------------------------------------------------------- shutdown
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


_KILL_MID_SHUTDOWN = textwrap.dedent("""
    import os, signal, sys
    import geofit.batch as batch
    from geofit.cli import main

    real = batch._shutdown

    def shutdown(client, cluster):
        os.kill(int(os.environ["SCHEDULER_PID"]), signal.SIGKILL)  # the scheduler dies
        return real(client, cluster)

    batch._shutdown = shutdown
    sys.exit(main(sys.argv[1:]))
""")


def test_scheduler_killed_mid_shutdown_exits_cleanly(tmp_path):
    """`geofit batch --scheduler ...`: the scheduler is killed while the client shuts down;
    every target had succeeded, so the command exits 0, writes its summary and prints no
    traceback. Scheduler and worker listen on 127.0.0.1 and are torn down."""
    mesh = _mesh(tmp_path / "in", "sphere")
    save_obj(mesh, ico_sphere(1).scale_verts(1.5))
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m"]
    import geofit

    # the processes import this checkout's geofit (they start in tmp_path)
    root = str(Path(geofit.__file__).resolve().parents[1])
    penv = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    log = open(tmp_path / "dask.log", "wb")  # noqa: SIM115 - closed below
    procs = []
    try:
        procs.append(subprocess.Popen(
            dask + ["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(port),
                    "--no-dashboard"], cwd=tmp_path, env=penv, stdout=log,
            stderr=subprocess.STDOUT))
        procs.append(subprocess.Popen(
            dask + ["distributed.cli.dask_worker", address, "--host", "127.0.0.1",
                    "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
                    "--local-directory", str(tmp_path)],
            cwd=tmp_path, env=penv, stdout=log, stderr=subprocess.STDOUT))
        env = {**penv, "SCHEDULER_PID": str(procs[0].pid)}
        res = subprocess.run(
            [sys.executable, "-c", _KILL_MID_SHUTDOWN, "batch", "fit-mesh", str(mesh),
             "--out", str(tmp_path / "out"), "--scheduler", address, "--time-budget", "120",
             "--no-progress"], env=env, capture_output=True, text=True, timeout=300)
        assert procs[0].wait(timeout=30) == -9  # the scheduler was killed
    finally:
        tree = set()
        for p in procs:
            if psutil.pid_exists(p.pid):
                tree |= {c.pid for c in psutil.Process(p.pid).children(recursive=True)}
            p.kill()
            p.wait(timeout=30)
        for pid in tree:
            try:
                psutil.Process(pid).kill()
            except psutil.NoSuchProcess:
                pass
        log.close()
    assert "Traceback" not in res.stderr and "Traceback" not in res.stdout, res.stderr[-3000:]
    assert res.returncode == 0, (res.stdout[-3000:], res.stderr[-3000:])
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["n_ok"] == 1 and summary["n_failed"] == 0
    assert "1 targets: 1 ok, 0 failed" in res.stdout
    assert (tmp_path / "out" / "index.html").is_file()
    print("timings", summary["timings"], "notes", summary["notes"])


def test_shutdown_errors_become_notes(monkeypatch):
    """Errors while Dask shuts down (timeouts, closed comms) are notes, never raised."""
    from distributed.comm.core import CommClosedError

    from geofit.batch import _shutdown

    class Stubborn:
        def __init__(self, exc):
            self.exc = exc

        def close(self, timeout=None):
            raise self.exc

    t = time.perf_counter()
    notes = _shutdown(Stubborn(CommClosedError("in <TCP (closed)>")),
                      Stubborn(TimeoutError("cluster close timed out")))
    assert len(notes) == 2 and "CommClosedError" in notes[0] and "TimeoutError" in notes[1]
    assert time.perf_counter() - t < 60


def test_unreachable_scheduler_still_writes_the_summary(tmp_path):
    """The cluster failing (no scheduler at the address) fails every target with the cause
    "environment" (a rerun redoes them), and the summary files are written all the same."""
    import dask

    _mesh(tmp_path / "in")
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        res = fit_many(tmp_path / "in", out=tmp_path / "out", progress=False,
                       scheduler=f"tcp://127.0.0.1:{_free_port()}")
    assert res.exit_code == 1 and res.n_failed == 1 and res[0].cause == "environment"
    assert res.notes and res.notes[0].startswith("the cluster failed")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["n_failed"] == 1 and summary["notes"] == res.notes
    assert (tmp_path / "out" / "index.html").is_file()
    rec = json.loads((tmp_path / "out" / "torus" / "result.json").read_text())
    assert _previous(tmp_path / "out" / "torus", rec["settings_hash"], False) is None
