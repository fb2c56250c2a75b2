"""geofit's one thread policy: how many threads, the BLAS/OpenMP/Open3D limits, and one pool.

Every component of geofit that runs work on several threads (the ray caster, the hard, soft and
point rasterizers, the volume and NeRF fits) asks this module, and no other module sets thread
counts, builds a thread pool or talks to BLAS:

- :func:`get_num_threads` is the number of threads geofit uses: the cores this process may run
  on (``len(os.sched_getaffinity(0))``, so ``taskset -c 0`` means 1), unless overridden by
  :func:`set_num_threads` or by the environment variable ``GEOFIT_NUM_THREADS`` (read when
  asked, so it may be set before or after import). :func:`set_num_threads` wins over the
  variable; ``set_num_threads(None)`` returns to the variable or the affinity.
- An override is also applied to the libraries geofit calls, read back through their own
  APIs: BLAS and OpenMP through ``threadpoolctl`` (OpenBLAS, MKL, BLIS alike), Open3D through
  ``open3d.utility.set_max_threads`` (its CPU kernels use oneTBB, not OpenMP, so
  threadpoolctl does not see them). By default neither is touched: OpenBLAS, OpenMP and TBB
  already size themselves by the CPU affinity.
- Embree's own threads (used only while a scene is committed) cannot be set: ``embreex``
  creates its device with ``rtcNewDevice(NULL)`` and exposes no configuration string; its TBB
  scheduler follows the CPU affinity (so ``taskset`` reaches it, :func:`set_num_threads` does
  not). Ray queries run on geofit's pool (below), one chunk per thread.
- :func:`one_blas_thread` is the "one BLAS thread per worker thread" context: while geofit's own
  threads each run numpy, BLAS must not add threads of its own, or the threads spin against
  each other. It is reference-counted, so overlapping uses from several threads restore the
  original limit only when the last one leaves. Enter it in the thread that starts the work
  (as :func:`parallel_map` does): measured with OpenBLAS 0.3.30/0.3.31, a limit set from a
  secondary thread after the main thread had set and restored one did not take effect.
- :func:`one_openmp_thread` is its OpenMP counterpart, entered in the worker itself: OpenMP's
  thread count is a per-thread setting (pykdtree's queries, called from a pool worker).
- :func:`parallel_map` runs ``fn`` over items on ONE reusable ``ThreadPoolExecutor`` (numpy and
  embreex release the GIL in their loops). The pool is created on first use and rebuilt only
  when the requested thread count changes; a call made from inside a pool worker runs inline
  (no nested pools, no deadlock).
"""
from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import numpy as np

__all__ = ["ENV_VAR", "cpu_count", "get_num_threads", "one_blas_thread", "one_openmp_thread",
           "parallel_map", "pool_size", "set_num_threads", "thread_environ"]

ENV_VAR = "GEOFIT_NUM_THREADS"

_LOCK = threading.RLock()
_OVERRIDE: int | None = None
_APPLIED: tuple[int, int] | None = None  # (count, len(sys.modules)) last pushed to BLAS
_O3D_APPLIED: int | None = None
_POOL: ThreadPoolExecutor | None = None
_POOL_SIZE = 0
_LOCAL = threading.local()
_BLAS_DEPTH = 0
_BLAS_LIMIT: Any = None
_CONTROLLER: tuple[int, Any] | None = None


def cpu_count() -> int:
    """Cores this process may run on (its CPU affinity; ``os.cpu_count()`` where unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def _check(n, name: str) -> int:
    if isinstance(n, str):
        try:
            n = int(n.strip())
        except ValueError:
            raise ValueError(f"{name}: expected an integer >= 1, got {n!r}") from None
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"{name}: expected an integer >= 1, got {n!r}")
    return int(n)


def get_num_threads() -> int:
    """The number of threads geofit uses.

    Returns
    -------
    int
        The value given to :func:`set_num_threads`, else ``GEOFIT_NUM_THREADS``, else the
        number of cores in this process's CPU affinity.

    Raises
    ------
    ValueError
        If ``GEOFIT_NUM_THREADS`` is set to something other than an integer >= 1.
    """
    if _OVERRIDE is not None:
        return _OVERRIDE
    env = os.environ.get(ENV_VAR, "").strip()
    if env:
        return _check(env, ENV_VAR)
    return cpu_count()


def set_num_threads(n: int | None) -> None:
    """Set the number of threads geofit, its BLAS/OpenMP and Open3D use (None: the default).

    Parameters
    ----------
    n : int or None
        Threads (>= 1). ``None`` removes the override: ``GEOFIT_NUM_THREADS`` if set, else the
        cores this process may run on.

    Raises
    ------
    ValueError
        If ``n`` is not None and not an integer >= 1.

    Examples
    --------
    >>> import geofit
    >>> geofit.set_num_threads(1)
    >>> geofit.get_num_threads()
    1
    >>> geofit.set_num_threads(None)
    """
    global _OVERRIDE
    n = None if n is None else _check(n, "n")
    with _LOCK:
        _OVERRIDE = n
        _sync_libraries()


def thread_environ(n: int) -> dict[str, str]:
    """The environment that gives a new process ``n`` threads: ``GEOFIT_NUM_THREADS`` and the
    variables OpenMP and BLAS read when they load (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
    ``MKL_NUM_THREADS``), for a process started before numpy (e.g. a Dask worker, whose nanny
    sets the BLAS ones to 1 unless told otherwise)."""
    t = str(_check(n, "n"))
    return {ENV_VAR: t, "OMP_NUM_THREADS": t, "OPENBLAS_NUM_THREADS": t, "MKL_NUM_THREADS": t}


def _controller():
    """A cached ``threadpoolctl.ThreadpoolController``, refreshed when modules were imported
    since (a new extension module may have loaded another BLAS)."""
    global _CONTROLLER
    import threadpoolctl  # kept local: threadpoolctl, loaded only when used (start-up)

    key = len(sys.modules)
    if _CONTROLLER is None or _CONTROLLER[0] != key:
        _CONTROLLER = (key, threadpoolctl.ThreadpoolController())
    return _CONTROLLER[1]


def _sync_libraries() -> None:
    """Push the thread count to BLAS/OpenMP and Open3D when it differs from their default (again
    whenever modules were imported since: a new extension may have loaded another BLAS)."""
    global _APPLIED
    n = get_num_threads()
    default = n == cpu_count()
    if not (default and _APPLIED is None):
        key = (n, len(sys.modules))
        if key != _APPLIED:
            _controller().limit(limits=n)  # every BLAS and OpenMP library, kept until changed
            _APPLIED = None if default else key
    _sync_open3d()


def _sync_open3d() -> None:
    """Open3D (if imported) gets the override; 0 restores its automatic default."""
    global _O3D_APPLIED
    o3d = sys.modules.get("open3d")
    if o3d is None or not hasattr(getattr(o3d, "utility", None), "set_max_threads"):
        return
    want = _OVERRIDE if _OVERRIDE is not None else (
        get_num_threads() if os.environ.get(ENV_VAR, "").strip() else None)
    if want != _O3D_APPLIED:
        o3d.utility.set_max_threads(0 if want is None else int(want))
        _O3D_APPLIED = want


def open3d_threads() -> int:
    """Apply the policy to Open3D (import it first) and return its thread count, read back."""
    import open3d  # kept local: Open3D takes ~1 s to import, loaded only when used (start-up)

    with _LOCK:
        _sync_open3d()
    return int(open3d.utility.get_max_threads())


def blas_threads() -> list[int]:
    """The thread count of every BLAS library loaded in this process, read by threadpoolctl."""
    import threadpoolctl  # kept local: threadpoolctl, loaded only when used (start-up)

    return [int(i["num_threads"]) for i in threadpoolctl.threadpool_info()
            if i.get("user_api") == "blas"]


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with one BLAS thread per calling thread (every BLAS, via threadpoolctl).

    Re-entrant and shared between threads: the first entry sets the limit, the last exit
    restores what was there before.
    """
    global _BLAS_DEPTH, _BLAS_LIMIT
    with _LOCK:
        if _BLAS_DEPTH == 0:
            _BLAS_LIMIT = _controller().limit(limits=1, user_api="blas")
        _BLAS_DEPTH += 1
    try:
        yield
    finally:
        with _LOCK:
            _BLAS_DEPTH -= 1
            if _BLAS_DEPTH == 0:
                _BLAS_LIMIT.restore_original_limits()
                _BLAS_LIMIT = None


@contextmanager
def one_openmp_thread() -> Iterator[None]:
    """Run the block with one OpenMP thread in the calling thread (every OpenMP runtime, via
    threadpoolctl), then restore the thread's previous count.

    OpenMP's thread count is a setting of each calling thread, so unlike BLAS's it must be
    limited in the thread that runs the work: a pool worker calling an OpenMP-parallel library
    (pykdtree's queries) would otherwise start a team as large as the machine on top of the
    pool's threads. Measured cost: 11 microseconds per use.
    """
    with _LOCK:
        limit = _controller().limit(limits=1, user_api="openmp")
    try:
        yield
    finally:
        limit.restore_original_limits()


def _mark_worker() -> None:
    _LOCAL.worker = True


def _pool(n: int) -> ThreadPoolExecutor:
    """The shared pool with ``n`` workers (rebuilt only when ``n`` changes). Caller holds _LOCK."""
    global _POOL, _POOL_SIZE
    if _POOL is None or _POOL_SIZE != n:
        if _POOL is not None:
            _POOL.shutdown(wait=False)  # already submitted work still runs
        _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="geofit",
                                   initializer=_mark_worker)
        _POOL_SIZE = n
    return _POOL


def pool_size() -> int:
    """Workers of the shared pool (0 before the first parallel call)."""
    return _POOL_SIZE


def in_worker() -> bool:
    """True when called from one of geofit's pool threads."""
    return getattr(_LOCAL, "worker", False)


def parallel_map(fn: Callable[[Any], Any], items: Iterable[Any],
                 n_threads: int | None = None) -> list[Any]:
    """``[fn(item) for item in items]``, in order, over the shared pool.

    Parameters
    ----------
    fn : callable
        Called once per item; should release the GIL for most of its time (numpy, embreex).
    items : iterable
        The work items (e.g. chunks of rays, views, bands of rows).
    n_threads : int, optional
        Threads to use (default :func:`get_num_threads`). With 1 thread, one item, or when
        called from inside a pool worker, the items run in the calling thread. While the items
        run on several threads, BLAS is held to one thread (:func:`one_blas_thread`).

    Returns
    -------
    list
        ``fn(item)`` for each item, in the order of ``items``.
    """
    items = list(items)
    n = get_num_threads() if n_threads is None else int(n_threads)
    if in_worker():
        return [fn(it) for it in items]
    with _LOCK:
        _sync_libraries()
    if n <= 1 or len(items) <= 1:
        return [fn(it) for it in items]
    with one_blas_thread():
        with _LOCK:
            futures = [_pool(n).submit(fn, it) for it in items]
        return [f.result() for f in futures]


# An override in the environment is applied to the libraries as soon as geofit is imported.
if os.environ.get(ENV_VAR, "").strip():
    try:
        _sync_libraries()
    except ValueError:  # reported by get_num_threads() where it is used
        pass
