"""The README and the docs/ pages stay true: their Python examples run, every geofit name they
cite exists, and the README keeps the two commands CI reads."""
import importlib.util
import pkgutil
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README] + sorted((ROOT / "docs").rglob("*.md"))
SKIP = "<!-- docs-test: skip -->"


def _blocks(text: str) -> list[str]:
    """The ```python blocks of a page, in order, without those marked with SKIP."""
    return [m.group(2) for m in re.finditer(r"(<!-- docs-test: skip -->\n)?```python\n(.*?)```",
                                            text, flags=re.S) if not m.group(1)]


def _name(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


RUNNABLE = [p for p in PAGES if _blocks(p.read_text(encoding="utf-8"))]


def test_readme_has_both_commands_and_ci_reads_the_test_command():
    """The two set-up commands are there, each on the second line after its marker, as .ci/run
    extracts them."""
    lines = README.read_text(encoding="utf-8").splitlines()
    for marker in ("<!-- main-command -->", "<!-- test-command -->"):
        i = lines.index(marker)
        assert lines[i + 1] == "```" and lines[i + 2].startswith("bash .ci/setup.sh && ")
    ci = (ROOT / ".ci" / "run").read_text()
    assert "<!-- test-command -->" in ci


def test_readme_is_a_front_page():
    """The README stays short (issue 23: at most 200 lines); the rest lives in docs/."""
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 200


def test_skip_marker_is_recognised():
    """A block preceded by the skip marker is left out, the others are kept in order."""
    text = (f"```python\na = 1\n```\n{SKIP}\n```python\nraise SystemExit\n```\n"
            "```python\nb = 2\n```\n")
    assert _blocks(text) == ["a = 1\n", "b = 2\n"]


@pytest.mark.parametrize("page", RUNNABLE, ids=_name)
def test_python_examples_run(page, tmp_path, monkeypatch):
    """The ```python blocks of a page run in order in one namespace, as a reader would paste
    them (offline: shipped or procedural data; files go to a temporary folder)."""
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "docs"}
    for i, block in enumerate(_blocks(page.read_text(encoding="utf-8"))):
        exec(compile(block, f"{_name(page)} python block {i}", "exec"), namespace)


NAMES = sorted({(name, _name(page)) for page in PAGES
                for name in re.findall(r"`(geofit(?:\.[A-Za-z_][A-Za-z0-9_]*)+)",
                                       page.read_text(encoding="utf-8"))})


@pytest.mark.parametrize("name,page", NAMES, ids=[f"{p}:{n}" for n, p in NAMES])
def test_every_cited_geofit_name_exists(name, page):
    """Names in backticks (the PyTorch3D tables, the guide) resolve to real objects."""
    assert pkgutil.resolve_name(name) is not None, f"{page} cites {name}"


def test_docstring_roles_become_markdown():
    """The site's griffe extension shows Sphinx roles as Markdown code spans, as Sphinx would."""
    pytest.importorskip("griffe")  # the docs extra
    spec = importlib.util.spec_from_file_location("_griffe_ext", ROOT / "docs" / "_griffe_ext.py")
    ext = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ext)
    convert = ext.rst_roles_to_markdown
    assert convert("see :func:`geofit.fit.fit_mesh`.") == "see `geofit.fit.fit_mesh`."
    assert convert(":class:`~geofit.structures.Mesh` and :py:meth:`x <a.b>`") == "`Mesh` and `x`"
    assert convert("``literal`` and :math:`x^2`") == "``literal`` and `x^2`"


def test_docstring_tables_become_markdown():
    """reST simple tables become Markdown tables (a row with a blank first cell continues the
    row above; a word running past a column start stays whole), and ``::`` becomes ``:``."""
    pytest.importorskip("griffe")
    spec = importlib.util.spec_from_file_location("_griffe_ext", ROOT / "docs" / "_griffe_ext.py")
    ext = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ext)
    rst = ("Formats::\n\n"
           "====  =======  ==========\n"
           "ext   reads    :func:`w` writes\n"
           "====  =======  ==========\n"
           "obj   reads_everything  OBJ\n"
           "                       + MTL\n"
           "====  =======  ==========\n"
           "\nafter\n")
    md = ext.rst_to_markdown(rst).splitlines()
    assert md[0] == "Formats:"
    table = [ln for ln in md if ln.startswith("|")]
    assert table == ["| ext | reads | `w` writes |", "| --- | --- | --- |",
                     "| obj | reads_everything | OBJ + MTL |"]
    assert md[-1] == "after"
