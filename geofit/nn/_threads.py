"""Control of numpy's BLAS thread count, and a two-way split of work over Python threads.

numpy's matmul calls OpenBLAS, which by default uses every core for one product. When geofit runs
two halves of a batch in two Python threads (numpy releases the GIL in matmul and in ufunc
loops), each half must use one BLAS thread, or the four threads on two cores spin against each
other. :func:`blas_threads` sets the count through OpenBLAS's own entry point (found in the
loaded library, as threadpoolctl does) and restores it afterwards; where no OpenBLAS is found it
does nothing.
"""
from __future__ import annotations

import ctypes
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

__all__ = ["blas_threads", "cpu_count", "run_parallel"]

_LOCK = threading.Lock()
_API: tuple[Any, Any] | None | bool = False  # False: not looked up yet


def _openblas():
    global _API
    if _API is not False:
        return _API
    _API = None
    try:
        import numpy  # noqa: F401  (make sure numpy's BLAS is loaded)

        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower()
                     and "numpy" in line.lower()}
    except OSError:
        return None
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in ("scipy_openblas_", "openblas_"):
            for suffix in ("64_", ""):
                s, g = f"{prefix}set_num_threads{suffix}", f"{prefix}get_num_threads{suffix}"
                if hasattr(lib, s) and hasattr(lib, g):
                    setter, getter = getattr(lib, s), getattr(lib, g)
                    setter.argtypes, setter.restype = [ctypes.c_int], None
                    getter.argtypes, getter.restype = [], ctypes.c_int
                    _API = (setter, getter)
                    return _API
    return None


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


@contextmanager
def blas_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` BLAS threads (no-op when OpenBLAS is not found)."""
    api = _openblas()
    if api is None:
        yield
        return
    setter, getter = api
    with _LOCK:
        old = getter()
        setter(int(n))
    try:
        yield
    finally:
        with _LOCK:
            setter(old)


def run_parallel(fn: Callable[[Any], Any], items: Sequence[Any], n_threads: int) -> list[Any]:
    """``[fn(item) for item in items]`` over ``n_threads`` Python threads, each with one BLAS
    thread (numpy releases the GIL in matmul and ufunc loops, so the threads share the cores
    without oversubscribing them; with ``n_threads <= 1`` it runs in the calling thread, also
    with one BLAS thread).
    """
    with blas_threads(1):
        if n_threads <= 1 or len(items) <= 1:
            return [fn(it) for it in items]  # chunks
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            return list(pool.map(fn, items))
