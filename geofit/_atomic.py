"""Atomic, durable file writes: the one way geofit puts a file on disk (issue 28 point 3).

Every writer (meshes, point clouds, captures, JSON, images, reports, batch results) goes
through :func:`atomic_write`: the content is written to a hidden temporary file in the target's
folder (same suffix, so libraries that choose the format by extension still do), checked
(``verify``: Open3D returns True after a short write, so its output size is checked against its
own header), flushed and ``fsync``-ed, moved over the target with ``os.replace`` (atomic on
POSIX), and the folder is ``fsync``-ed so the rename survives a power cut. On any failure the
temporary file is removed and the error is raised: the target holds the old file or the
complete new one, never a mix. A process killed mid-write leaves at most a hidden
``.NAME.tmp-PID-XXXXXXXX.SUFFIX`` file beside the target.
"""
from __future__ import annotations

import errno
import json
import os
import uuid
from pathlib import Path
from typing import Any, Callable

__all__ = ["atomic_write", "write_bytes", "write_json", "write_text", "KILL_POINTS"]

#: The steps of a write, in order; ``_hook(step)`` is called at each (a test sets ``_hook`` in
#: a forked child to kill it there and check that the target is never left half-written).
KILL_POINTS = ("created", "partial", "written", "verified", "flushed", "synced", "replaced",
               "done")

_CHUNK = 1 << 20


def _hook(step: str) -> None:
    """Called at each of :data:`KILL_POINTS` (a no-op; replaced by tests)."""


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:  # a folder that cannot be opened (some network filesystems): best effort
        return
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def _temp_name(path: Path) -> Path:
    return path.with_name(f".{path.stem[:100]}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
                          f"{path.suffix}")


def atomic_write(path, write: Callable[[Path], Any], *,
                 verify: Callable[[Path], None] | None = None, _partial: bool = True) -> Path:
    """Write a file through ``write(tmp)`` and put it in place atomically and durably.

    Parameters
    ----------
    path : str or os.PathLike
        The target; replaced only once the new content is complete and on disk.
    write : callable
        ``write(tmp)`` writes the whole content to the path ``tmp`` (same folder and suffix as
        ``path``). It may also write through a file object it opens itself.
    verify : callable, optional
        ``verify(tmp)`` raises OSError when the written file is incomplete (e.g. a library that
        reports success after a short write).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        Naming ``path`` (errno kept: ENOSPC for a full disk, EFBIG over a file-size limit),
        when writing, syncing or renaming fails; the target is then unchanged.
    """
    path = Path(path)
    tmp = _temp_name(path)
    try:
        with open(tmp, "xb"):
            pass
        _hook("created")
        write(tmp)
        if _partial:  # a library writing to the path: its output is complete or cut here
            _hook("partial")
        _hook("written")
        if verify is not None:
            verify(tmp)
        _hook("verified")
        fd = os.open(tmp, os.O_RDWR)
        try:
            _hook("flushed")
            os.fsync(fd)
        finally:
            os.close(fd)
        _hook("synced")
        os.replace(tmp, path)
        _hook("replaced")
        _fsync_dir(path.parent)
        _hook("done")
    except OSError as exc:
        _remove(tmp)
        if str(path) in str(exc):
            raise
        raise OSError(exc.errno, f"{path}: could not write the file "
                                 f"({exc.strerror or exc}); the previous file, if any, is "
                                 "unchanged") from exc
    except BaseException:
        _remove(tmp)
        raise
    return path


def _remove(tmp: Path) -> None:
    try:
        tmp.unlink()
    except OSError:
        pass


def _write_chunks(tmp: Path, data) -> None:
    view = memoryview(data).cast("B")
    with open(tmp, "wb") as fh:
        for i, start in enumerate(range(0, max(len(view), 1), _CHUNK)):  # 1 MiB chunks
            fh.write(view[start:start + _CHUNK])
            if i == 0:
                fh.flush()
                _hook("partial")


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and durably (see :func:`atomic_write`)."""
    return atomic_write(path, lambda tmp: _write_chunks(tmp, data),
                        verify=lambda tmp: _check_size(tmp, len(data)), _partial=False)


def write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically and durably."""
    return write_bytes(path, text.encode(encoding))


def write_json(path, obj, *, indent: int = 1, default=None) -> Path:
    """Write ``obj`` as indented JSON (plus a final newline) atomically and durably.

    ``default`` converts objects json does not know (e.g. numpy values); non-finite floats are
    written as json writes them unless the caller made them plain first.
    """
    return write_text(path, json.dumps(obj, indent=indent, default=default) + "\n")


def _check_size(tmp: Path, expected: int) -> None:
    got = os.stat(tmp).st_size
    if got != expected:
        raise OSError(errno.EIO, f"{tmp}: short write ({got} of {expected} bytes)")
