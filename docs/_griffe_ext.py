"""Griffe extensions for the docs site (loaded by mkdocstrings: ``extensions`` in ``mkdocs.yml``).

``RuntimeAll``: a package whose ``__all__`` is computed (``sorted(base.__all__ + ...)``) cannot
be read by static analysis, which would then document none of its re-exported names; this
imports such modules and takes their real ``__all__``.

``RuntimeDocstrings``: a docstring filled in at import time from a ``%(name)s`` template (the
shared paragraphs of ``geofit.cameras.conversions``) is taken from the imported object.

``RstRoles``: Sphinx roles in docstrings become Markdown.

geofit's numpydoc docstrings cross-reference with Sphinx roles (``:func:`geofit.fit.fit_mesh```,
``:class:`~geofit.structures.Mesh```). MkDocs renders Markdown, where a role would show as raw
text; this turns each into a code span (``~`` keeps the last name, as Sphinx shows it).
"""
from __future__ import annotations

import importlib
import inspect
import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?[a-z]+:`(~?)([^`<]*?)(?:\s*<([^`>]+)>)?`")


def _span(match: re.Match) -> str:
    tilde, text, target = match.groups()
    text = text.strip()
    if tilde:
        text = text.rsplit(".", 1)[-1]
    return f"`{text or target}`"


def rst_roles_to_markdown(text: str) -> str:
    """``:role:`target``` -> `` `target` ``, ``:role:`~a.b``` -> `` `b` ``,
    ``:role:`t <x>``` -> `` `t` ``."""
    return _ROLE.sub(_span, text)


class RstRoles(griffe.Extension):
    """Rewrite the roles of every docstring as griffe loads it."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = rst_roles_to_markdown(obj.docstring.value)


class RuntimeAll(griffe.Extension):
    """Take ``__all__`` from the imported module wherever the source computes it."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        stack = [pkg]
        while stack:
            mod = stack.pop()
            stack.extend(m for m in mod.modules.values() if not m.is_alias)
            assigned = mod.members.get("__all__")
            if assigned is None or isinstance(getattr(assigned, "value", None), griffe.ExprList):
                continue  # no __all__, or a literal list griffe reads itself
            mod.exports = list(importlib.import_module(mod.path).__all__)


def _runtime(path: str):
    """The imported object at a dotted path (module, then attributes)."""
    parts = path.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(path)


class RuntimeDocstrings(griffe.Extension):
    """Take the docstring from the imported object where the source holds a ``%(...)s`` template."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        stack = [pkg]
        while stack:
            obj = stack.pop()
            stack.extend(m for m in obj.members.values() if not m.is_alias)
            if obj.docstring is not None and "%(" in obj.docstring.value:
                doc = inspect.cleandoc(_runtime(obj.path).__doc__)
                obj.docstring.value = rst_roles_to_markdown(doc)  # RstRoles saw the template
