"""The one path policy for every file a loaded file names (issue 28 point 1).

An OBJ names its MTL and textures, an MTL its images, a glTF its buffers and images, a capture
its images and masks. Every such reference, and every candidate a loader tries for it (an
extension-less ``file_path`` plus ``.png``, ``.jpg``, ...), goes through
:meth:`PathPolicy.resolve`, which returns only a checked path:

* a regular file (not a FIFO, a device, a socket or a folder: opening a FIFO blocks forever);
* after ``os.path.realpath`` (``..`` and every symlink resolved), inside the policy's root
  folder or one of the folders the caller allowed; absolute references and written ``..`` are
  refused too, whatever they resolve to;
* a name without control characters and within the system's name and path lengths.

``allow_outside=True`` lifts the folder rule only; non-regular files are refused always.
The path returned is the real path, so the file opened is the file checked.

:func:`trimesh_resolver` is the same policy as a ``trimesh.resolvers.Resolver``, for the
trimesh route (glTF buffers and images named by URI).
"""
from __future__ import annotations

import functools
import os
import stat
from pathlib import Path

__all__ = ["PathPolicy", "check_input_file", "trimesh_resolver"]

_NAME_MAX = 255
_PATH_MAX = 4096


def check_input_file(path, what: str = "file") -> Path:
    """The file a user names directly: it must exist and be a regular file (after symlinks).

    Raises FileNotFoundError when it does not exist and ValueError for a FIFO, a device, a
    socket or a folder, naming the path.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except (OSError, ValueError) as exc:  # name too long, NUL byte, permission, loops
        raise ValueError(f"{path}: cannot open the {what} ({_why(exc)})") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{path}: expected a regular {what}, got {_kind(st.st_mode)}")
    return path


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _why(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc)[:120] or type(exc).__name__


class PathPolicy:
    """Where the files named by one input may be.

    Parameters
    ----------
    root : str or os.PathLike
        The folder of the file naming the references (relative references are joined to it).
    allowed : sequence of path-like, optional
        Further folders whose files may be read (e.g. a capture's root when the references
        are relative to its ``images/`` folder).
    allow_outside : bool
        Lift the folder rule (absolute paths and paths leaving the folders are then followed).
        Non-regular files stay refused.
    folder_name : str
        What to call the folder in messages (e.g. ``"capture folder"``).
    """

    def __init__(self, root, allowed=(), *, allow_outside: bool = False,
                 folder_name: str = "folder"):
        self.root = Path(root)
        self.folder_name = folder_name
        self.allow_outside = bool(allow_outside)
        self._real = [os.path.realpath(f) for f in (self.root, *allowed)]

    def inside(self, real: str) -> bool:
        """Whether the real path ``real`` lies in one of the policy's folders."""
        return any(os.path.commonpath([r, real]) == r for r in self._real)

    def resolve(self, ref, where: str, *, extensions=(), required: bool = True,
                base=None) -> Path | None:
        """The checked real path of ``ref`` (or of ``ref`` plus one of ``extensions``).

        Parameters
        ----------
        ref : str
            The reference as written (``/`` or ``\\`` separators).
        where : str
            What names it (file, line or field), put first in every error.
        extensions : sequence of str
            Suffixes tried, in order, after ``ref`` itself; every candidate is checked.
        required : bool
            Raise FileNotFoundError when no candidate exists; otherwise return None.
        base : path-like, optional
            The folder a relative ``ref`` is joined to (default: the root).

        Returns
        -------
        Path or None
            The real path of the first existing candidate.

        Raises
        ------
        ValueError
            A reference that is not a non-empty string, holds a control character, is too
            long, is absolute or leaves the folders (unless ``allow_outside``), or a candidate
            that exists but is not a regular file or resolves (symlinks) outside the folders.
        FileNotFoundError
            When ``required`` and no candidate exists.
        """
        if not isinstance(ref, str) or not ref.strip():
            raise ValueError(f"{where}: expected a non-empty relative path, got {ref!r:.80}")
        if any(ord(c) < 32 or c == "\x7f" for c in ref):
            raise ValueError(f"{where}: the path has a control character")
        written = ref.replace("\\", "/")
        longest = max((len(os.fsencode(p)) for p in written.split("/")), default=0)
        if longest > _NAME_MAX or len(os.fsencode(written)) > _PATH_MAX:
            raise ValueError(f"{where}: the path {written[:60]!r}... is too long ({len(written)} "
                             f"characters; names may have at most {_NAME_MAX} bytes, paths "
                             f"{_PATH_MAX})")
        p = Path(written)
        folder = Path(base) if base is not None else self.root
        desc = f"the {self.folder_name} {folder}"
        if not self.allow_outside:
            norm = os.path.normpath(written)
            if p.is_absolute():
                raise ValueError(f"{where}: absolute path {ref!r} refused (referenced files must "
                                 f"lie in {desc}; pass allow_outside=True to follow such paths)")
            if norm == ".." or norm.startswith("../"):
                raise ValueError(f"{where}: path {ref!r} leaves {desc} ('..'; pass "
                                 "allow_outside=True to follow such paths)")
        target = p if p.is_absolute() else folder / p
        for ext in ("", *extensions):  # every candidate goes through the same checks
            cand = target.with_name(target.name + ext) if ext else target
            try:
                real = os.path.realpath(cand, strict=True)
                st = os.stat(real)
            except FileNotFoundError:
                continue
            except (OSError, RuntimeError, ValueError) as exc:  # loops, permissions
                raise ValueError(f"{where}: path {str(cand)!r} cannot be resolved "
                                 f"({_why(exc)})") from None
            if not self.allow_outside and not self.inside(real):
                raise ValueError(f"{where}: path {cand.name!r} resolves outside {desc} (a "
                                 f"symlink to {real!r}); pass allow_outside=True to follow such "
                                 "paths")
            if not stat.S_ISREG(st.st_mode):
                raise ValueError(f"{where}: {str(cand)!r} is {_kind(st.st_mode)}, expected a "
                                 "regular file")
            return Path(real)
        if required:
            tried = f" (also tried {', '.join(extensions[:3])}, ...)" if extensions else ""
            raise FileNotFoundError(f"{where}: {str(target)!r} not found{tried}")
        return None

    def under(self, sub) -> "PathPolicy":
        """The same policy (same folders) with relative references joined to ``root / sub``."""
        out = PathPolicy(self.root / sub, allow_outside=self.allow_outside,
                         folder_name=self.folder_name)
        out._real = list(self._real)
        return out

    def read_bytes(self, ref, where: str, *, limit: int | None = None) -> bytes:
        """The bytes of a checked reference (at most ``limit`` bytes, else ValueError)."""
        path = self.resolve(ref, where)
        with open(path, "rb") as fh:
            data = fh.read(-1 if limit is None else limit + 1)
        if limit is not None and len(data) > limit:
            raise ValueError(f"{where}: {str(path)!r} is larger than {limit} bytes")
        return data


@functools.cache
def _resolver_class():
    """The trimesh ``Resolver`` subclass (built on first use: trimesh is imported lazily)."""
    from trimesh.resolvers import Resolver

    class PolicyResolver(Resolver):
        """Every ``get`` goes through a :class:`PathPolicy`; nothing is written or listed."""

        def __init__(self, policy: PathPolicy, where: str):
            self.policy = policy
            self.where = where

        def get(self, name):
            from urllib.parse import unquote

            return self.policy.read_bytes(unquote(str(name)), f"{self.where}: {str(name)[:80]!r}")

        def write(self, name, data):
            raise ValueError(f"{self.where}: a loader does not write files")

        def namespaced(self, namespace):
            return PolicyResolver(self.policy.under(namespace), self.where)

        def keys(self):
            return iter(())

    return PolicyResolver


def trimesh_resolver(policy: PathPolicy, where: str):
    """A ``trimesh.resolvers.Resolver`` refusing what ``policy`` refuses (``where`` names the
    input in errors)."""
    return _resolver_class()(policy, where)
