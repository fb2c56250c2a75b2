"""Memory guard: estimate the bytes of a call's largest buffers and refuse it before allocating.

Every renderer, rasterizer, raymarcher, fit and loader that can be asked for more memory than
the machine has calls :func:`check_allocation` with an estimate computed from its *settings*
(image size, points per pixel, volume size, batch size, an image header), before it allocates.

The limit is, in order of precedence: the ``limit`` argument (a call's ``memory_limit=``), the
environment variable ``GEOFIT_MEMORY_LIMIT`` (bytes, with an optional suffix ``K``, ``M``, ``G``
or ``T``, powers of 1024; e.g. ``4G``), or half of the memory the kernel reports as available
(``MemAvailable`` in ``/proc/meminfo``; 8 GiB where that file does not exist).
"""
from __future__ import annotations

import os

__all__ = ["DEFAULT_FRACTION", "check_allocation", "memory_limit", "parse_bytes"]

DEFAULT_FRACTION = 0.5
_FALLBACK_AVAILABLE = 8 * 1024**3
_SUFFIX = {"": 1, "B": 1, "K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}


def parse_bytes(value, name: str = "memory_limit") -> int:
    """A byte count from an int/float or a string such as ``"4G"``, ``"512M"``, ``"1000000"``.

    Parameters
    ----------
    value : int, float or str
        Bytes, or a number followed by ``K``, ``M``, ``G`` or ``T`` (optionally ``iB``/``B``:
        ``4GiB``, ``4GB`` and ``4G`` all mean 4 * 1024**3).
    name : str
        What to call the value in an error message.

    Returns
    -------
    int
        The positive number of bytes.

    Raises
    ------
    ValueError
        If the value is not a positive, finite byte count.

    Examples
    --------
    >>> parse_bytes("4G"), parse_bytes("512m"), parse_bytes(1000)
    (4294967296, 536870912, 1000)
    """
    if isinstance(value, bool):
        raise ValueError(f"{name}: expected a positive byte count such as 4G, got {value!r}")
    if isinstance(value, str):
        s = value.strip().upper().replace(" ", "")
        for tail in ("IB", "B"):
            if s.endswith(tail) and len(s) > len(tail) and s[-len(tail) - 1] in "KMGT":
                s = s[: -len(tail)]
                break
        unit = s[-1:] if s[-1:] in _SUFFIX else ""
        number = s[: len(s) - len(unit)]
        try:
            x = float(number) * _SUFFIX[unit]
        except ValueError:
            raise ValueError(f"{name}: expected a positive byte count such as 4G, got "
                             f"{value!r}") from None
    else:
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected a positive byte count such as 4G, got "
                             f"{value!r}") from None
    if not (x > 0 and x < float("inf")):
        raise ValueError(f"{name}: expected a positive byte count such as 4G, got {value!r}")
    return int(x)


def _available_bytes() -> int:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return _FALLBACK_AVAILABLE


def memory_limit(limit=None) -> int:
    """The byte limit a guarded call may allocate (see the module notes for the precedence).

    Parameters
    ----------
    limit : int, float, str or None
        An explicit limit (``memory_limit=`` of a call); None to use ``GEOFIT_MEMORY_LIMIT`` or
        half of the available memory.

    Returns
    -------
    int
        Bytes.
    """
    if limit is not None:
        return parse_bytes(limit, "memory_limit")
    env = os.environ.get("GEOFIT_MEMORY_LIMIT", "").strip()
    if env:
        return parse_bytes(env, "GEOFIT_MEMORY_LIMIT")
    return int(DEFAULT_FRACTION * _available_bytes())


def _fmt(n: float) -> str:
    for unit, size in (("TiB", 1024**4), ("GiB", 1024**3), ("MiB", 1024**2), ("KiB", 1024)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} bytes"


def check_allocation(nbytes, setting: str = "settings", what: str = "buffers",
                     limit=None) -> int:
    """Refuse a call whose estimated allocation exceeds the memory limit.

    Parameters
    ----------
    nbytes : int or float
        Estimated bytes of the call's largest simultaneous buffers, computed from its settings
        (Python ints do not overflow; floats may be inf).
    setting : str
        The setting(s) the user should change, named in the error (e.g. ``"image_size"``).
    what : str
        What the buffers are (e.g. ``"the (N, H, W, K) fragments"``).
    limit : int, float, str or None
        Explicit limit, see :func:`memory_limit`.

    Returns
    -------
    int
        The limit that was applied, in bytes.

    Raises
    ------
    ValueError
        Naming ``setting``, the estimate and the limit, when ``nbytes`` exceeds the limit.

    Examples
    --------
    >>> check_allocation(1000, "image_size", limit="1M")
    1048576
    >>> check_allocation(2**40, "image_size", "the fragments", limit="1G")
    Traceback (most recent call last):
    ...
    ValueError: image_size: the fragments would need about 1 TiB, over the memory limit of 1 GiB (reduce image_size, or raise the limit with GEOFIT_MEMORY_LIMIT, e.g. GEOFIT_MEMORY_LIMIT=32G)
    """
    lim = memory_limit(limit)
    if not nbytes <= lim:  # also catches NaN
        raise ValueError(
            f"{setting}: {what} would need about {_fmt(float(nbytes))}, over the memory limit of "
            f"{_fmt(lim)} (reduce {setting}, or raise the limit with GEOFIT_MEMORY_LIMIT, e.g. "
            f"GEOFIT_MEMORY_LIMIT=32G)")
    return lim


def check_count(value, name: str, bytes_each, *, low: int = 1, what: str | None = None,
                limit=None, error: type[Exception] = ValueError) -> int:
    """A count the user passes (samples, rays, resolution, width), checked before allocating.

    The count must be an integer (``error``, ValueError by default as
    :func:`geofit._validate.check_int`, otherwise; a bool included) ``>= low`` (ValueError), and ``value * bytes_each`` (the estimated bytes of what the count sizes) must
    fit the memory limit (:func:`check_allocation`: ValueError with the estimate).

    Parameters
    ----------
    value : int
        The count as given.
    name : str
        The argument's name, used in error messages.
    bytes_each : int or float
        Estimated bytes per unit of the count.
    low : int
        Smallest allowed value.
    what : str, optional
        What the buffers are, for the message (default: ``"{value} {name}"``).
    limit : int, float, str or None
        Explicit memory limit, see :func:`memory_limit`.
    error : {ValueError, TypeError}
        Raised for a value that is not an integer.

    Returns
    -------
    int
        The count.

    Examples
    --------
    >>> check_count(1000, "num_samples", 200)
    1000
    >>> check_count(10**12, "num_samples", 200, limit="1G")
    Traceback (most recent call last):
    ...
    ValueError: num_samples: 1,000,000,000,000 num_samples would need about 182 TiB, over the memory limit of 1 GiB (reduce num_samples, or raise the limit with GEOFIT_MEMORY_LIMIT, e.g. GEOFIT_MEMORY_LIMIT=32G)
    """
    import numbers

    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise error(f"{name}: expected an integer >= {low}, got {value!r:.40}")
    n = int(value)
    if n < low:
        raise ValueError(f"{name}: expected an integer >= {low}, got {n}")
    check_allocation(n * bytes_each, setting=name, what=what or f"{n:,} {name}", limit=limit)
    return n


def check_mlp_size(width: int, layers: int, name: str = "n_hidden_neurons", *,
                   limit=None) -> None:
    """Refuse an MLP whose weights, gradients and two Adam moments (4 float64 copies of about
    ``width**2 * (layers + 1)`` numbers) exceed the memory limit, before it is built."""
    check_allocation(32 * int(width) ** 2 * (int(layers) + 1), setting=name,
                     what=f"an MLP {int(width)} wide and {int(layers)} deep (weights, gradients "
                          f"and Adam moments)", limit=limit)
