"""The README stays true: its Python examples run and every geofit name it cites exists."""
import importlib
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
TEXT = README.read_text(encoding="utf-8")
BLOCKS = re.findall(r"```python\n(.*?)```", TEXT, flags=re.S)


def test_readme_has_both_commands_and_ci_reads_the_test_command():
    """The two set-up commands are there, and .ci/run extracts the test one after its marker."""
    assert "<!-- main-command -->" in TEXT and "<!-- test-command -->" in TEXT
    ci = (README.parent / ".ci" / "run").read_text()
    assert "test-command" in ci


@pytest.mark.parametrize("i", range(len(BLOCKS)))
def test_python_examples_run(i, tmp_path, monkeypatch):
    """Each ```python block of the README executes (offline: procedural data)."""
    monkeypatch.chdir(tmp_path)
    exec(compile(BLOCKS[i], f"README block {i}", "exec"), {"__name__": "readme"})


def _resolve(dotted: str):
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


NAMES = sorted(set(re.findall(r"`(geofit(?:\.[A-Za-z_][A-Za-z0-9_]*)+)", TEXT)))


@pytest.mark.parametrize("name", NAMES)
def test_every_cited_geofit_name_exists(name):
    """Names in the 'coming from PyTorch3D' table and elsewhere resolve to real objects."""
    assert _resolve(name) is not None
