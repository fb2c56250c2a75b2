"""Griffe extensions for the docs site (loaded by mkdocstrings: ``extensions`` in ``mkdocs.yml``).

``RuntimeAll``: a package whose ``__all__`` is computed (``sorted(base.__all__ + ...)``) cannot
be read by static analysis, which would then document none of its re-exported names; this
imports such modules and takes their real ``__all__``.

``RuntimeDocstrings``: a docstring filled in at import time from a ``%(name)s`` template (the
shared paragraphs of ``geofit.cameras.conversions``) is taken from the imported object.

``RstToMarkdown``: Sphinx roles (``:func:`x```) and reST simple tables (``=== ===`` borders) in
docstrings become Markdown code spans and tables; MkDocs would show them as raw text.

geofit's numpydoc docstrings cross-reference with Sphinx roles (``:func:`geofit.fit.fit_mesh```,
``:class:`~geofit.structures.Mesh```). MkDocs renders Markdown, where a role would show as raw
text; this turns each into a code span (``~`` keeps the last name, as Sphinx shows it).
"""
from __future__ import annotations

import importlib
import inspect
import pkgutil
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


_BORDER = re.compile(r"^( *)=+( +=+)+ *$")


def _cells(line: str, starts: list[int]) -> list[str]:
    """Split a table row at the column starts (a start inside a word moves to the next space)."""
    bounds = []
    for s in starts[1:]:
        while s < len(line) and line[s - 1] != " ":
            s += 1
        bounds.append(s)
    edges = [starts[0]] + bounds + [len(line)]
    return [line[a:b].strip() for a, b in zip(edges[:-1], edges[1:])]


_LITERAL = re.compile(r"(?<=\S)::$", re.MULTILINE)


def rst_to_markdown(text: str) -> str:
    """Tables, then roles (the tables' columns are laid out on the raw text), then a paragraph's
    closing ``::`` (reST's literal-block marker; the indented block is already Markdown code)."""
    return _LITERAL.sub(":", rst_roles_to_markdown(rst_tables_to_markdown(text)))


def rst_tables_to_markdown(text: str) -> str:
    """reST simple tables (a header between the first two borders, or none) -> Markdown tables;
    a row whose first cell is blank continues the row above."""
    lines, out, i = text.split("\n"), [], 0
    while i < len(lines):
        m = _BORDER.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent = m.group(1)
        starts = [k.start() for k in re.finditer(r"=+", lines[i])]
        borders, rows, header_rows, j = [i], [], None, i + 1
        while j < len(lines) and len(borders) < 3:
            if _BORDER.match(lines[j]):
                borders.append(j)
                if len(borders) == 2:
                    header_rows = len(rows)
                    if j + 1 >= len(lines) or not lines[j + 1].strip():
                        break  # a table without a header ends at its second border
            elif not lines[j].strip():
                break
            else:
                cells = _cells(lines[j], starts)
                if rows and not cells[0]:
                    rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], cells)]
                else:
                    rows.append(cells)
            j += 1
        if len(borders) == 3:
            header, body = rows[:header_rows][:1] or [[""] * len(starts)], rows[header_rows:]
        else:
            header, body = rows[:1], rows[1:]
        if out and out[-1].strip():
            out.append("")
        table = [header[0], ["---"] * len(starts)] + body
        out += [indent + "| " + " | ".join(r) + " |" for r in table] + [""]
        i = borders[-1] + 1
    return "\n".join(out)


class RstToMarkdown(griffe.Extension):
    """Rewrite the roles and simple tables of every docstring as griffe loads it."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = rst_to_markdown(obj.docstring.value)


def _objects(pkg: griffe.Object):
    """Every object under ``pkg`` (itself included) that is defined there, not an alias."""
    stack = [pkg]
    while stack:
        obj = stack.pop()
        stack.extend(m for m in obj.members.values() if not m.is_alias)
        yield obj


class RuntimeAll(griffe.Extension):
    """Take ``__all__`` from the imported module wherever the source computes it."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        for mod in _objects(pkg):
            assigned = mod.members.get("__all__") if mod.is_module else None
            if assigned is None or isinstance(getattr(assigned, "value", None), griffe.ExprList):
                continue  # no __all__, or a literal list griffe reads itself
            mod.exports = list(importlib.import_module(mod.path).__all__)


class RuntimeDocstrings(griffe.Extension):
    """Take the docstring from the imported object where the source holds a ``%(...)s`` template."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        for obj in _objects(pkg):
            if obj.docstring is not None and "%(" in obj.docstring.value:
                doc = inspect.cleandoc(pkgutil.resolve_name(obj.path).__doc__)
                obj.docstring.value = rst_to_markdown(doc)
