"""Every geofit module whose docstrings carry ``>>>`` examples runs them as doctests.

The modules are found by walking the package (``pkgutil.walk_packages``), so a new module with
examples is tested without being listed here.
"""
import doctest
import importlib
import pkgutil
from pathlib import Path

import pytest

import geofit


def _modules_with_examples():
    """Names of the geofit modules whose source contains a ``>>>`` prompt."""
    names = []
    for info in pkgutil.walk_packages(geofit.__path__, prefix="geofit."):
        spec = importlib.util.find_spec(info.name)
        origin = getattr(spec, "origin", None)
        if origin and origin.endswith(".py") and ">>>" in Path(origin).read_text(encoding="utf-8"):
            names.append(info.name)
    return sorted(names)


MODULES = _modules_with_examples()


def test_discovery_finds_the_known_example_modules():
    """Discovery reaches nested packages (not only a hand-kept list)."""
    for name in ("geofit.cameras.look_at", "geofit.render.soft.contour", "geofit.fit.mesh",
                 "geofit.loss.chamfer", "geofit.metrics"):
        assert name in MODULES
    assert len(MODULES) >= 40


@pytest.mark.parametrize("name", MODULES)
def test_module_examples_run(name, tmp_path, monkeypatch):
    """The module's Examples sections run and print what they show."""
    monkeypatch.chdir(tmp_path)  # examples that write files write into tmp_path
    mod = importlib.import_module(name)
    result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS,
                             verbose=False)
    assert result.attempted > 0, f"{name} has '>>>' in its source but no collected example"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed"
