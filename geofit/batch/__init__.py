"""Many scenes, many machines: one Dask task per target, on this machine or on any Dask cluster.

:func:`fit_many` fits (or renders) each target in its own Dask task. A task receives a path and
its settings, loads its own input (no Embree scene, Open3D object or large array crosses a
process boundary), runs geofit's workflow, and writes ``OUT/<name>/result.json`` (status,
message, metrics, seconds, parameter count, history, the settings and their hash) and its
outputs (mesh, volume, weights, pictures), each atomically (a temporary file, then
``os.replace``). Each fit runs with its own defaults (those of ``geofit.fit_*`` and of the
``geofit fit-*`` commands); only the options given are passed on. A target is ``"ok"`` when its
fit made at least one step and ended well by its own account; otherwise, or on an error, it is
recorded as ``"failed"`` (error type, message and cause) and the batch goes on. A rerun into the
same ``OUT`` skips every target whose ``result.json`` holds the same settings hash (the hash
covers the task, the settings and the input files' sizes and modification times) and redoes the
failures caused by the environment (disk full, memory, a killed worker); ``retry_failed=True``
also recomputes the other failed ones, ``force=True`` all. Results stream in as they finish
(``distributed.as_completed``) with a tqdm progress bar. Dask's shutdown never fails a batch:
its errors become ``notes``.

Without ``client`` or ``scheduler``, :func:`fit_many` starts a ``distributed.LocalCluster`` of
worker processes on 127.0.0.1 (no dashboard) and tears it down afterwards; with
``scheduler="tcp://host:port"`` (or a ``distributed.Client``) the same call runs on any Dask
cluster, e.g. ``dask scheduler`` plus ``dask worker`` processes, dask-jobqueue, Kubernetes or
SSH. ``OUT`` must then be a folder every worker can write (a shared file system).

Threads: each Dask worker runs one target at a time, and each target limits its compute
threads (ray casting, rendering, BLAS, Open3D) to ``threads_per_worker`` through
``geofit.set_num_threads`` and the ``GEOFIT_NUM_THREADS`` / ``OMP_NUM_THREADS`` environment
variables, so that ``n_workers * threads_per_worker`` never exceeds the cores.

Scheduling: before the first target, a worker plugin (:class:`geofit.batch._warm.WarmUp`) sets
every worker's thread limits and imports what the task needs (geofit's modules, Open3D,
Pillow), once per worker rather than inside the first task. The targets are submitted
largest input first (longest-processing-time-first: the last targets to start are the short
ones, so no worker waits long for the last one), and the embedded cluster's scheduler keeps
them queued until a worker is free (``distributed.scheduler.worker-saturation`` 1.0), so a
free worker always takes the largest remaining target. Results are collected in batches
(``as_completed(..., with_results=True).batches()``).
"""
from __future__ import annotations

import csv
import hashlib
import inspect
import json
import os
import time
import uuid
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from ._options import (
    ACCURACY,
    CAPTURE_MARKERS,
    MESH_SUFFIXES,
    RESULT_FILE,
    RESULT_SCHEMA,
    TASK_OPTIONS,
    TASKS,
    Option,
    check_input,
    check_output_folder,
    is_capture,
)

__all__ = [
    "ACCURACY",
    "CAPTURE_MARKERS",
    "LOCAL_CLUSTER",
    "LOCAL_SCHEDULER_CONFIG",
    "MESH_SUFFIXES",
    "TASKS",
    "TASK_OPTIONS",
    "BatchResult",
    "Option",
    "TargetResult",
    "check_input",
    "check_output_folder",
    "expand_targets",
    "fit_many",
    "input_bytes",
    "largest_first",
    "settings_hash",
    "task_settings",
    "thread_env",
]


def _check_task(task) -> str:
    if task not in TASK_OPTIONS:
        raise ValueError(f"task: expected one of {TASKS}, got {task!r}")
    return task


def task_settings(task: str, **kwargs) -> dict[str, Any]:
    """The full settings of ``task``: its defaults updated with ``kwargs`` (None keeps the
    default), each value checked against the option's type and choices.

    Raises
    ------
    ValueError
        For an unknown task, an option the task does not have, a value outside the choices,
        or a count or budget that is not positive.
    TypeError
        For a value of the wrong type.
    """
    opts = TASK_OPTIONS[_check_task(task)]
    unknown = sorted(set(kwargs) - set(opts))
    if unknown:
        raise ValueError(f"{unknown[0]}: not an option of task {task!r}; expected one of "
                         f"{sorted(opts)}")
    out = {}
    for name, opt in opts.items():
        v = kwargs.get(name)
        if v is None:
            out[name] = opt.default
            continue
        if opt.type is float and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        if not isinstance(v, opt.type) or isinstance(v, bool):
            raise TypeError(f"{name}: expected {opt.type.__name__}, got {v!r}")
        choices = opt.allowed()
        if choices is not None and v not in choices:
            raise ValueError(f"{name}: expected one of {choices}, got {v!r}")
        if opt.type in (int, float) and name not in ("seed", "elev") and not v > 0:
            raise ValueError(f"{name}: expected a positive number, got {v!r}")
        out[name] = v
    return out


# ------------------------------------------------------------------------------ targets
def expand_targets(targets: str | os.PathLike | Iterable[str | os.PathLike],
                   task: str = "fit-mesh") -> list[tuple[str, Path]]:
    """Files and folders -> ``[(name, path), ...]`` in a stable order.

    A file is one target. A folder expands to its mesh files (:data:`MESH_SUFFIXES`, not
    recursive), and, for the multi-view tasks, is itself one target when it is a capture
    (:func:`geofit.batch._options.is_capture`) or else contributes its capture sub-folders.
    ``name`` is the file or folder stem, made unique with a short hash of the path when two
    targets share a stem; it names the target's output folder.

    Raises
    ------
    FileNotFoundError
        For a path that does not exist.
    ValueError
        When nothing is left to run.
    """
    multiview = _check_task(task) in ("fit-views", "fit-volume", "fit-nerf")
    if isinstance(targets, (str, os.PathLike)):
        targets = [targets]
    paths: list[Path] = []
    for t in targets:
        p = Path(t)
        if not p.exists():
            raise FileNotFoundError(f"targets: {p} does not exist")
        if p.is_file() or (multiview and is_capture(p)):
            paths.append(p)
        else:
            paths += [c for c in sorted(p.iterdir())
                      if (c.is_file() and c.suffix.lower() in MESH_SUFFIXES)
                      or (multiview and is_capture(c))]
    seen: set[Path] = set()
    unique = []
    for p in paths:
        r = p.resolve()
        if r not in seen:
            seen.add(r)
            unique.append(r)
    if not unique:
        raise ValueError(f"targets: no mesh files{' or captures' if multiview else ''} in "
                         f"{[str(t) for t in targets]}")
    stems: dict[str, int] = {}
    for p in unique:
        stems[p.stem] = stems.get(p.stem, 0) + 1
    return [(p.stem if stems[p.stem] == 1 else
             f"{p.stem}-{hashlib.sha1(str(p).encode()).hexdigest()[:6]}", p) for p in unique]


def _fingerprint(path: Path) -> list:
    """(relative name, size, mtime_ns) of the target's files: changes when an input changes,
    without reading it."""
    files = [path] if path.is_file() else sorted(q for q in path.rglob("*") if q.is_file())
    out = []
    for q in files:
        st = q.stat()
        out.append([q.name if q == path else str(q.relative_to(path)), st.st_size,
                    st.st_mtime_ns])
    return out


def settings_hash(task: str, path: Path, settings: dict) -> str:
    """SHA-256 of the task, the settings, the result schema and the input's fingerprint."""
    blob = json.dumps({"task": task, "settings": settings, "schema": RESULT_SCHEMA,
                       "input": _fingerprint(Path(path))}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


# ------------------------------------------------------------------------------ results
@dataclass
class TargetResult:
    """One target's outcome (a row of :class:`BatchResult`).

    Attributes
    ----------
    name : str
        Output folder name under ``out``.
    target : str
        Input path.
    task : str
    status : str
        ``"ok"`` or ``"failed"``.
    message : str
        The fit's status and message, or the error (``"TypeName: message"``).
    error_type : str or None
        Exception type of a failure (``"FitStatus"`` when the fit ended non-finite/diverged,
        ``"NoProgress"`` when it made no step, ``"KilledWorker"`` etc. when the task itself
        was lost).
    cause : str or None
        Of a failure: ``"environment"`` (disk full, memory, a killed worker, a lost task: a
        rerun redoes it by default) or ``"target"`` (the input or the fit: redone only with
        ``retry_failed``).
    accuracy : float
        The task's headline metric (:data:`ACCURACY`); -1 when not measured.
    seconds : float
        Wall time of the task on its worker (load, fit, evaluation, writing).
    load_seconds, fit_seconds, eval_seconds : float
        Its parts: reading/rendering the input, the solver's own time, the metrics.
    cpu_seconds : float
        CPU time of the worker process during the task (all its threads): against
        ``seconds``, how long the task waited for a core on a busy machine.
    n_params : int
        Free parameters of the fit (0 for ``render``).
    fit_status : str or None
        The fit's own status (``"converged"``, ``"time_budget"``, ...).
    metrics : dict
        All metrics of the task.
    settings_hash : str
    reused : bool
        True when an earlier run's ``result.json`` (same settings hash) was kept.
    picture : str or None
        Path of the target's picture relative to ``out``.
    outputs : dict
        The target's output files (``"mesh"``, ``"volume"``, ``"weights"``, views), relative
        to ``out``.
    worker : str
        ``host:pid`` of the worker process that computed the result ("" for a lost task).
    """

    name: str
    target: str
    task: str
    status: str
    message: str = ""
    error_type: str | None = None
    cause: str | None = None
    accuracy: float = -1.0
    seconds: float = 0.0
    load_seconds: float = 0.0
    fit_seconds: float = 0.0
    eval_seconds: float = 0.0
    cpu_seconds: float = 0.0
    n_params: int = 0
    fit_status: str | None = None
    metrics: dict = field(default_factory=dict)
    settings_hash: str = ""
    reused: bool = False
    picture: str | None = None
    outputs: dict = field(default_factory=dict)
    worker: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @classmethod
    def from_record(cls, rec: dict, reused: bool = False) -> TargetResult:
        """A row from a ``result.json`` record."""
        pic = rec.get("picture")
        err = rec.get("error") or {}
        return cls(name=rec["name"], target=rec["target"], task=rec["task"],
                   status=rec["status"], message=rec.get("message", ""),
                   error_type=err.get("type"), cause=rec.get("cause"),
                   accuracy=float(rec.get("accuracy", -1.0)),
                   seconds=float(rec.get("seconds", 0.0)),
                   load_seconds=float(rec.get("load_seconds", 0.0)),
                   fit_seconds=float(rec.get("fit_seconds", 0.0)),
                   eval_seconds=float(rec.get("eval_seconds", 0.0)),
                   cpu_seconds=float(rec.get("cpu_seconds", 0.0)),
                   n_params=int(rec.get("n_params", 0)), fit_status=rec.get("fit_status"),
                   metrics=dict(rec.get("metrics") or {}),
                   settings_hash=rec.get("settings_hash", ""), reused=reused,
                   picture=None if pic is None else f"{rec['name']}/{pic}",
                   outputs={k: f"{rec['name']}/{v}" for k, v in
                            (rec.get("outputs") or {}).items()},
                   worker=f"{rec['host']}:{rec['pid']}" if rec.get("pid") else "")


_CSV_FIELDS = [f.name for f in fields(TargetResult) if f.name not in ("metrics", "outputs")]


@dataclass
class BatchResult(Sequence):
    """The table :func:`fit_many` returns: one :class:`TargetResult` per target, in target order.

    Attributes
    ----------
    rows : list of TargetResult
    task : str
    out : Path
        The output folder.
    settings : dict
        The task's settings.
    seconds : float
        Wall time of the whole call (cluster start and tear-down included).
    n_workers : int
        Dask workers used (0 when every target was reused and no cluster was needed).
    threads_per_worker : int
    scheduler : str
        ``"local"`` for the embedded LocalCluster, else the scheduler's address.
    timings : dict
        Seconds of the call's phases: ``"cluster_start"`` (starting the LocalCluster or
        connecting to the scheduler), ``"warm_up"`` (the workers' thread limits and imports,
        all workers in parallel), ``"tasks"`` (submitting the targets until the last result),
        ``"tear_down"`` and ``"summary"`` (the summary files); empty when nothing was run.
    notes : list of str
        What went wrong around the targets (the cluster failing, Dask's shutdown timing out):
        one line each, also in ``summary.json``; a note never fails the batch by itself.
    """

    rows: list
    task: str
    out: Path
    settings: dict = field(default_factory=dict)
    seconds: float = 0.0
    n_workers: int = 0
    threads_per_worker: int = 1
    scheduler: str = "local"
    timings: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def __getitem__(self, i):
        return self.rows[i]

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self) -> Iterator[TargetResult]:
        return iter(self.rows)

    @property
    def n_ok(self) -> int:
        return sum(r.ok for r in self.rows)

    @property
    def n_failed(self) -> int:
        return len(self.rows) - self.n_ok

    @property
    def n_reused(self) -> int:
        return sum(r.reused for r in self.rows)

    @property
    def n_result_workers(self) -> int:
        """Worker processes that computed the results listed (this run's and, for reused
        rows, the earlier runs')."""
        return len({r.worker for r in self.rows if r.worker})

    @property
    def exit_code(self) -> int:
        """0 when every target succeeded, 1 when some failed (the command line's exit code)."""
        return 0 if self.n_failed == 0 else 1

    def metric_names(self) -> list[str]:
        names: list[str] = []
        for r in self.rows:
            names += [k for k in r.metrics if k not in names]
        return names

    def to_csv(self, path: str | os.PathLike) -> Path:
        """One line per target: the row's fields and one column per metric (written atomically)."""
        metrics = self.metric_names()

        def write(p: Path) -> None:
            with open(p, "w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(_CSV_FIELDS + metrics)
                for r in self.rows:
                    d = asdict(r)
                    w.writerow([d[k] for k in _CSV_FIELDS] + [r.metrics.get(m, "")
                                                              for m in metrics])

        from ._tasks import atomic_write  # the workers' module (heavy): imported when used

        return atomic_write(Path(path), write)

    def to_dict(self) -> dict:
        return {"schema": "geofit-batch-summary/1", "task": self.task, "out": str(self.out),
                "settings": self.settings, "seconds": self.seconds,
                "n_targets": len(self.rows), "n_ok": self.n_ok, "n_failed": self.n_failed,
                "n_reused": self.n_reused, "n_workers": self.n_workers,
                "threads_per_worker": self.threads_per_worker, "scheduler": self.scheduler,
                "n_result_workers": self.n_result_workers, "timings": self.timings,
                "notes": self.notes,
                "accuracy": {"metric": ACCURACY[self.task][0], "label": ACCURACY[self.task][1]},
                "targets": [asdict(r) for r in self.rows]}

    def __repr__(self) -> str:
        return (f"BatchResult({self.task}: {len(self.rows)} targets, {self.n_ok} ok, "
                f"{self.n_failed} failed, {self.n_reused} reused, {self.seconds:.1f} s)")


def _previous(dest: Path, digest: str, retry_failed: bool) -> dict | None:
    """The earlier ``result.json`` of a target when it holds the same settings hash and is
    ``"ok"``, or ``"failed"`` because of the target itself and ``retry_failed`` is off. A
    failure whose cause was the environment (disk full, memory, a killed worker, a lost task:
    ``"cause": "environment"``) is never kept: the rerun redoes it."""
    try:
        rec = json.loads((dest / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if rec.get("schema") != RESULT_SCHEMA or rec.get("settings_hash") != digest:
        return None
    from_environment = rec.get("lost") or rec.get("cause") == "environment"
    if rec.get("status") == "ok" or (not retry_failed and not from_environment):
        rec.pop("history", None)
        return rec
    return None


# ------------------------------------------------------------------------------ cluster
def _plan_threads(n_workers: int | None, threads: int | None) -> tuple[int, int]:
    """(workers, threads per worker) of the embedded cluster, with workers x threads <= cores."""
    from .._threads import cpu_count

    cores = cpu_count()
    if n_workers is None:
        n_workers = max(1, cores // (threads or 1))
    if threads is None:
        threads = max(1, cores // n_workers)
    if n_workers * threads > cores:
        raise ValueError(f"n_workers x threads_per_worker: {n_workers} x {threads} = "
                         f"{n_workers * threads} exceeds the {cores} cores of this machine")
    return n_workers, threads


def thread_env(threads: int) -> dict[str, str]:
    """Environment of a worker process limited to ``threads`` compute threads, set before the
    process starts: ``GEOFIT_NUM_THREADS`` (geofit's thread policy, :mod:`geofit._threads`,
    which also limits BLAS and Open3D) and ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
    ``MKL_NUM_THREADS`` (read when OpenMP and BLAS load). The BLAS ones matter: a Dask nanny
    sets all three to 1 before it starts a worker (``distributed.nanny.pre-spawn-environ``),
    and geofit leaves BLAS alone when its thread count equals the cores, so a 1 worker x 2
    threads cluster would otherwise run BLAS on one thread."""
    from .._threads import thread_environ  # geofit.batch stays light for the CLI's checks

    return thread_environ(int(threads))


#: Keyword arguments of every ``LocalCluster`` geofit starts: no dashboard, and the scheduler's
#: remaining HTTP endpoint (health, metrics) on a free port of 127.0.0.1 rather than 8787.
LOCAL_CLUSTER = {"dashboard_address": None,
                 "scheduler_kwargs": {"dashboard_address": "127.0.0.1:0"}}


#: Scheduler settings of the embedded cluster: a target goes to a worker only when that worker
#: is free (no target waits on a busy worker while another is idle at the end of a batch).
LOCAL_SCHEDULER_CONFIG = {"distributed.scheduler.worker-saturation": 1.0}


@contextmanager
def _environ(values: dict[str, str]) -> Iterator[None]:
    """``os.environ`` updated with ``values`` inside the block; those variables restored after
    (also undoing what a Dask nanny writes into this process's environment for them)."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _start_local(n_workers: int, threads: int):
    """A LocalCluster of ``n_workers`` single-slot worker processes with ``threads`` compute
    threads each, and its client.

    The BLAS/OpenMP variables must be in the environment the worker process is spawned with
    (its ``env`` is applied after numpy has loaded BLAS): they go into Dask's
    ``distributed.nanny.pre-spawn-environ``, whose values Dask takes from ``os.environ`` when
    set there, hence :func:`_environ` around the start."""
    import dask  # kept local: Dask, loaded only when used (start-up)
    from distributed import Client, LocalCluster  # kept local: start-up

    from .._threads import ENV_VAR

    env = thread_env(threads)
    at_spawn = {k: v for k, v in env.items() if k != ENV_VAR}
    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ"), **at_spawn}
    with _environ(at_spawn), dask.config.set(  # read when the nannies and scheduler start
            {**LOCAL_SCHEDULER_CONFIG, "distributed.nanny.pre-spawn-environ": pre_spawn}):
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                               host="127.0.0.1", env=env, **LOCAL_CLUSTER)
    client = Client(cluster)
    client.wait_for_workers(n_workers)
    return cluster, client


def _warm_up(client, task: str, threads: int) -> dict:
    """Register the warm-up plugin (thread limits and imports on every worker, present and
    future); returns once every current worker has run it."""
    from ._warm import WarmUp  # kept local: imports Dask's distributed (start-up)

    return client.register_plugin(WarmUp(task, threads))


def input_bytes(path: str | os.PathLike) -> int:
    """Bytes of a target's input files (a file, or every file under a capture folder): the
    size by which :func:`fit_many` orders the targets, largest first."""
    return sum(size for _, size, _ in _fingerprint(Path(path)))


def _remote_threads(client, threads: int | None) -> int:
    """Compute threads per task on an existing cluster: as given, else the cores of the
    smallest worker host divided by the task slots Dask runs on it."""
    if threads is not None:
        return threads
    info = _workers(client)
    slots: dict[str, int] = {}
    for w in info.values():
        slots[w["host"]] = slots.get(w["host"], 0) + int(w["nthreads"])
    if not slots:
        return 1
    from .._threads import cpu_count

    cores = client.run(cpu_count)
    per_host: dict[str, int] = {}
    for addr, c in cores.items():
        host = info[addr]["host"] if addr in info else addr
        per_host[host] = c
    return max(1, min(per_host.get(h, 1) // s for h, s in slots.items()))


def _workers(client) -> dict:
    """The scheduler's ``{address: info}`` of every worker (recent ``distributed`` lists only
    the first five unless asked for all)."""
    if "n_workers" in inspect.signature(client.scheduler_info).parameters:
        return client.scheduler_info(n_workers=-1)["workers"]
    return client.scheduler_info()["workers"]  # pragma: no cover - older distributed


# ------------------------------------------------------------------------------ the call
def fit_many(targets, task: str = "fit-mesh", out: str | os.PathLike = "batch_out", *,
             client=None, scheduler: str | None = None, n_workers: int | None = None,
             threads_per_worker: int | None = None, progress: bool = True,
             force: bool = False, retry_failed: bool = False, summary: bool = True,
             **fit_kwargs) -> BatchResult:
    """Fit (or render) many targets, one Dask task each, and write a result per target.

    Parameters
    ----------
    targets : path or iterable of paths
        Mesh files, folders of mesh files, and for the multi-view tasks capture folders
        (:func:`expand_targets`).
    task : {"fit-mesh", "render", "fit-views", "fit-volume", "fit-nerf"}
        What to run per target (:data:`TASKS`).
    out : path
        Output folder: ``out/<name>/result.json`` and the outputs of each target, and with
        ``summary`` ``summary.json``, ``summary.csv``, ``summary.png`` and ``index.html``.
    client : distributed.Client, optional
        Run on this client's cluster (left running).
    scheduler : str, optional
        Address of a running Dask scheduler (``"tcp://host:8786"``); connected to and
        disconnected from (the cluster is left running).
    n_workers : int, optional
        Worker processes of the embedded ``LocalCluster`` (default: cores // threads).
    threads_per_worker : int, optional
        Compute threads per target (ray casting, rendering, BLAS, Open3D). Default: the cores
        divided by the workers (on an existing cluster: by the task slots on each host). The
        embedded cluster refuses ``n_workers * threads_per_worker`` above the cores.
    progress : bool
        A tqdm progress bar on stderr.
    force : bool
        Recompute every target, even those whose earlier result has the same settings hash.
    retry_failed : bool
        Recompute the targets that failed earlier with the same settings hash (by default a
        rerun keeps them: the same input and settings fail the same way). Failures caused by
        the environment (disk full, memory, a killed worker, a lost task) are always retried.
    summary : bool
        Write the summary files into ``out``.
    **fit_kwargs
        The task's options (:data:`TASK_OPTIONS`), e.g. ``time_budget=5.0``,
        ``recipe="coarse-to-fine"``.

    Returns
    -------
    BatchResult
        One :class:`TargetResult` per target, in target order; ``exit_code`` is 0 when all
        succeeded.

    Raises
    ------
    ValueError
        For an unknown task or option, a bad option value, thread counts above the cores, no
        targets, or an unusable ``out`` (a file, a folder that cannot be created or written),
        all before the first task. A failing *target* never raises: it is recorded as
        ``"failed"``; nor does a failing cluster or its shutdown (see ``notes``).
    FileNotFoundError
        For a target path that does not exist.

    Notes
    -----
    The embedded cluster's workers are new processes (multiprocessing's "spawn"), which import
    the calling script again: in a script, call :func:`fit_many` under
    ``if __name__ == "__main__":``.

    Examples
    --------
    >>> from geofit.batch import fit_many
    >>> table = fit_many(["a.obj", "b.obj"], out="out", time_budget=5.0)  # doctest: +SKIP
    >>> table.to_csv("out/table.csv")  # doctest: +SKIP
    """
    t0 = time.perf_counter()
    settings = task_settings(task, **fit_kwargs)
    items = expand_targets(targets, task)
    out = check_output_folder(Path(out).resolve(), "out")  # before the first task
    if client is not None and scheduler is not None:
        raise ValueError("client, scheduler: give at most one of them")
    for v, nm in ((n_workers, "n_workers"), (threads_per_worker, "threads_per_worker")):
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
            raise ValueError(f"{nm}: expected an integer >= 1, got {v!r}")
    if client is None and scheduler is None:
        n_workers, threads_per_worker = _plan_threads(n_workers, threads_per_worker)
    key = ACCURACY[task][0]
    rows: dict[str, TargetResult] = {}
    todo = []
    for name, path in items:
        digest = settings_hash(task, path, settings)
        prev = None if force else _previous(out / name, digest, retry_failed)
        if prev is not None:
            rows[name] = TargetResult.from_record(prev, reused=True)
        else:
            todo.append({"task": task, "path": str(path), "name": name, "out": str(out),
                         "settings": settings, "settings_hash": digest,
                         "accuracy_key": key})
    used_workers, where = 0, "local" if client is None and scheduler is None else "cluster"
    timings: dict[str, float] = {}
    notes: list[str] = []
    if todo:
        own = client is None
        cluster = None
        try:
            t = time.perf_counter()
            if client is None and scheduler is not None:
                from distributed import Client  # kept local: start-up

                client = Client(scheduler)
            elif client is None:
                cluster, client = _start_local(n_workers, threads_per_worker)
            if cluster is None:
                threads_per_worker = _remote_threads(client, threads_per_worker)
                where = str(client.scheduler.address)
            used_workers = len(_workers(client))
            timings["cluster_start"] = time.perf_counter() - t
            t = time.perf_counter()
            _warm_up(client, task, threads_per_worker)
            timings["warm_up"] = time.perf_counter() - t
            for spec in todo:
                spec["threads"] = threads_per_worker
            t = time.perf_counter()
            _run(client, todo, progress, rows)
            timings["tasks"] = time.perf_counter() - t
            # the scheduler's list may lag behind an external cluster's workers: count those
            # that computed a result too
            ran = {rows[spec["name"]].worker for spec in todo if spec["name"] in rows}
            used_workers = max(used_workers, len(_workers(client)), len(ran - {""}))
        except Exception as exc:  # noqa: BLE001 - the cluster failed, not a target: record it
            notes.append(f"the cluster failed: {type(exc).__name__}: {exc}")
            for spec in todo:
                if spec["name"] not in rows:
                    rows[spec["name"]] = TargetResult.from_record(_lost(spec, exc))
        finally:
            t = time.perf_counter()
            notes += _shutdown(client if own else None, cluster)
            if "tasks" in timings:
                timings["tear_down"] = time.perf_counter() - t
    result = BatchResult([rows[name] for name, _ in items], task, out, settings,
                         n_workers=used_workers, threads_per_worker=threads_per_worker or 1,
                         scheduler=where, timings=timings, notes=notes)
    if summary:
        t = time.perf_counter()
        result.seconds = t - t0
        from ._summary import write_summary  # matplotlib: imported when used

        write_summary(result)  # summary.json holds the seconds up to here
        timings["summary"] = time.perf_counter() - t
    result.seconds = time.perf_counter() - t0
    return result


#: Seconds the client and the embedded cluster get to close before they are left to the
#: process's exit (distributed's own default waits longer, then raises).
SHUTDOWN_TIMEOUT = 10.0


def _shutdown(client, cluster) -> list[str]:
    """Close ``client`` and ``cluster`` (either may be None) quietly; returns notes.

    Every result is on disk when this runs, so nothing that happens while Dask shuts down may
    fail the batch: a shutdown timeout, a comm the scheduler already closed
    (``CommClosedError``), a worker that will not stop, each becomes a one-line note in the
    summary instead of a traceback, and distributed's own log lines about them are muted.
    """
    import logging

    notes = []
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        for what, obj in (("client", client), ("cluster", cluster)):
            if obj is None:
                continue
            try:
                obj.close(timeout=SHUTDOWN_TIMEOUT)
            except Exception as exc:  # noqa: BLE001 - see the docstring
                notes.append(f"closing the {what}: {type(exc).__name__}: {exc}".rstrip(": "))
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)
    return notes


def largest_first(todo: list[dict]) -> list[dict]:
    """The specs ordered by input size, largest first (stable for equal sizes): the
    longest-processing-time-first order, with the input size as the estimate of the work."""
    return sorted(todo, key=lambda spec: -input_bytes(spec["path"]))


def _run(client, todo: list[dict], progress: bool, rows: dict[str, TargetResult]) -> None:
    """Submit one task per spec, largest input first, and collect the records in batches as
    they finish, into ``rows`` (kept when the cluster fails half-way)."""
    import uuid

    from distributed import as_completed
    from tqdm.auto import tqdm

    from ._tasks import run_target

    todo = largest_first(todo)
    # One task group for the scheduler (the first element of a tuple key names it), so the
    # targets are queued on the scheduler and handed out by priority; the token keeps two
    # batches on one cluster apart.
    group, token = f"geofit-{todo[0]['task']}", uuid.uuid4().hex[:12]
    futures = {}
    for rank, spec in enumerate(todo):
        f = client.submit(run_target, spec, pure=False, priority=len(todo) - rank,
                          key=(group, token, spec["name"]))
        futures[f] = spec
    n_failed = 0
    with tqdm(total=len(todo), desc=f"geofit batch {todo[0]['task']}", unit="target",
              disable=not progress) as bar:
        done = as_completed(futures, with_results=True, raise_errors=False)
        for batch in done.batches():
            for fut, rec in batch:
                spec = futures.pop(fut)
                if isinstance(rec, BaseException):  # the task was lost (worker died, ...)
                    rec = _lost(spec, rec)
                row = TargetResult.from_record(rec)
                rows[spec["name"]] = row
                n_failed += not row.ok
            bar.set_postfix_str(f"{row.name}: {row.status}; {n_failed} failed")
            bar.update(len(batch))


def _lost(spec: dict, exc: BaseException) -> dict:
    """The record of a task that did not return (its worker died, the cluster failed):
    written by the client, with the cause ``"environment"`` (a rerun retries it)."""
    from ._tasks import write_json

    rec = {"schema": RESULT_SCHEMA, "name": spec["name"], "target": spec["path"],
           "task": spec["task"], "settings": spec["settings"],
           "settings_hash": spec["settings_hash"], "status": "failed",
           "message": f"{type(exc).__name__}: {exc}",
           "error": {"type": type(exc).__name__, "message": str(exc)}, "metrics": {},
           "accuracy": -1.0, "seconds": 0.0, "n_params": 0, "picture": None, "lost": True,
           "cause": "environment"}
    dest = Path(spec["out"]) / spec["name"]
    try:
        dest.mkdir(parents=True, exist_ok=True)
        write_json(dest / RESULT_FILE, {**rec, "history": None})
    except OSError:  # the disk is what failed: the summary still lists the target
        pass
    return rec

