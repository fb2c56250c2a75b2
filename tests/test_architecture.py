"""The layering of docs/architecture.md: no geofit module imports a layer above its own.

Every import of every module under geofit/ (top-level and inside functions alike) is read with
``ast``; an import of a higher layer fails the test unless it is listed in ``ALLOWED`` with its
reason. A new top-level module or package must be given a layer here (and in the document).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "geofit"

# Layer of each top-level module or package of geofit (docs/architecture.md, "Layers"): a module
# may import its own layer and the ones below, never one above.
LAYERS = {
    # 0: foundations
    "_validate": 0, "_threads": 0, "_memory": 0, "_foreign": 0, "_atomic": 0,
    # 1: data types and leaf utilities
    "structures": 1, "cameras": 1, "nn": 1, "viz": 1,
    # 2: geometry over the data types
    "shapes": 2, "ops": 2, "raycast": 2, "io": 2,
    # 3: losses, metrics and renderers
    "loss": 3, "metrics": 3, "render": 3,
    # 4: the tutorials' data
    "data": 4, "datasets": 4,
    # 5: fitting
    "fit": 5, "batch": 5,
    # 6: facades and reports over the fits
    "report": 6, "pytorch3d": 6,
    # 7: applications
    "tutorials": 7, "cli": 7,
    # 8: the package namespace and ``python -m geofit``
    "": 8, "__main__": 8,
}

# (importing module or package prefix, imported layer): reason.
ALLOWED = {
    ("geofit.io.views", "datasets"): "load_views returns geofit.datasets.MultiViewDataset, the "
    "one multi-view dataset type; datasets renders views (it needs render), so it sits above io "
    "and the import is made inside the function that builds the dataset",
    ("geofit.cli", ""): "geofit --version reads geofit.__version__",
    ("geofit.batch._tasks", ""): "limit_threads calls geofit.set_num_threads/get_num_threads "
    "through the namespace (they live in geofit._threads, layer 0: importing them from there "
    "removes this exception)",
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _layer_key(module: str) -> str:
    """The top-level part of a geofit module name (``""`` for the package itself)."""
    parts = module.split(".")
    if len(parts) == 1:
        return ""
    name = parts[1]
    # an attribute of the package namespace (geofit.__version__), not a module
    if not (PACKAGE / name).is_dir() and not (PACKAGE / f"{name}.py").is_file():
        return ""
    return name


def imported_modules(module: str, source: str, is_package: bool = False) -> list[str]:
    """Every geofit module (or package attribute) that ``source`` of ``module`` imports."""
    package = module if is_package else module.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if node.module is None:  # from . import a, b: each name may be a module
                out += [f"{target}.{a.name}" for a in node.names]
            else:
                out.append(target)
    return [m for m in out if m == "geofit" or m.startswith("geofit.")]


def violations(module: str, source: str, is_package: bool = False) -> list[str]:
    """``"module -> imported (layer i above layer j)"`` for each upward import not allowed."""
    own = _layer_key(module)
    bad = []
    for target in imported_modules(module, source, is_package):
        key = _layer_key(target)
        if key not in LAYERS:
            bad.append(f"{module} -> {target}: layer of {key!r} unknown")
            continue
        if LAYERS[key] <= LAYERS[own]:
            continue
        if any(module.startswith(prefix) and key == k for prefix, k in ALLOWED):
            continue
        bad.append(f"{module} (layer {LAYERS[own]}) -> {target} (layer {LAYERS[key]})")
    return bad


def _modules():
    return sorted(PACKAGE.rglob("*.py"))


def test_every_top_level_module_has_a_layer():
    """A new top-level module or package gets a layer here and in docs/architecture.md."""
    names = {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    names |= {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert sorted(names - set(LAYERS)) == []


def test_no_module_imports_a_layer_above_its_own():
    bad = []
    for path in _modules():
        bad += violations(_module_name(path), path.read_text(encoding="utf-8"),
                          path.name == "__init__.py")
    assert bad == [], "\n".join(bad)


def test_every_allowed_exception_is_still_used():
    """An exception that no module needs any more is removed from ``ALLOWED``."""
    used = set()
    for path in _modules():
        module = _module_name(path)
        targets = imported_modules(module, path.read_text(encoding="utf-8"),
                                   path.name == "__init__.py")
        for prefix, key in ALLOWED:
            if module.startswith(prefix) and any(_layer_key(t) == key for t in targets):
                used.add((prefix, key))
    assert sorted(set(ALLOWED) - used) == []


@pytest.mark.parametrize("module, source, n_bad", [
    ("geofit.render.mesh.renderer", "from ...fit import fit_mesh", 1),          # render -> fit
    ("geofit.structures.mesh", "def f():\n    from ..render import MeshRenderer", 1),
    ("geofit.structures.mesh", "import geofit.tutorials.runner", 1),
    ("geofit.render.mesh.renderer", "from ...structures import Mesh\nfrom .. import lighting", 0),
    ("geofit.fit.views", "from ..render.soft import rasterize_soft", 0),         # fit -> render
    ("geofit.io.views", "from ..datasets import MultiViewDataset", 0),           # allowed
    ("geofit.io.obj", "from ..datasets import MultiViewDataset", 1),             # not allowed
    ("geofit.ops.sampling", "from .. import loss", 1),                           # from . import
])
def test_the_checker_finds_upward_imports(module, source, n_bad):
    """The checker itself: relative, absolute and function-local imports are all seen."""
    assert len(violations(module, source)) == n_bad
