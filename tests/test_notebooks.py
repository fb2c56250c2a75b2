"""Every notebook in notebooks/ runs top to bottom at reduced size (GEOFIT_QUICK=1).

Each notebook is executed with nbclient in a temporary working directory, cell by cell, so a
failure names the cell. Notebooks must be committed with their outputs cleared. GEOFIT_DATA is
unset so the notebooks use geofit's procedural stand-ins (the suite must not depend on the
tutorial data being present).
"""
from __future__ import annotations

from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))

#: Third-party banners no output may show: Open3D's Jupyter WebVisualizer, Filament's engine
#: log, Open3D's INFO lines.
BANNERS = ("Jupyter environment detected", "WebVisualizer", "WebRTC", "FEngine",
           "CircularBuffer", "[Open3D INFO]", "Vulkan device driver")


def _texts(cell) -> list[str]:
    """The text of a cell's outputs (streams, plain-text results, errors)."""
    out = []
    for o in cell.get("outputs", []):
        if o.get("output_type") == "stream":
            out.append(o.get("text", ""))
        elif "data" in o:
            out.append(str(o["data"].get("text/plain", "")))
        elif o.get("output_type") == "error":
            out.append(" ".join(o.get("traceback", [])))
    return out


def _imports():
    nbformat = pytest.importorskip("nbformat", reason="nbformat is not installed "
                                   "(pip install nbclient nbformat ipykernel)")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is not installed "
                                   "(pip install nbclient nbformat ipykernel)")
    pytest.importorskip("ipykernel", reason="ipykernel is not installed "
                        "(pip install nbclient nbformat ipykernel)")
    return nbformat, nbclient


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_committed_without_outputs(path):
    """Notebooks are committed with outputs and execution counts cleared."""
    nbformat, _ = _imports()
    nb = nbformat.read(path, as_version=4)
    dirty = [i for i, c in enumerate(nb.cells) if c.cell_type == "code"
             and (c.get("outputs") or c.get("execution_count") is not None)]
    assert not dirty, f"{path.name}: cells {dirty} have outputs; clear them before committing"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path, monkeypatch):
    """The notebook executes without error with GEOFIT_QUICK=1 (the failing cell is named), and
    no output shows a third-party banner."""
    nbformat, nbclient = _imports()
    from nbclient.exceptions import CellExecutionError

    nb = nbformat.read(path, as_version=4)
    monkeypatch.setenv("GEOFIT_QUICK", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.delenv("GEOFIT_DATA", raising=False)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    with client.setup_kernel():
        for index, cell in enumerate(nb.cells):  # cells, in order
            if cell.cell_type != "code":
                continue
            try:
                client.execute_cell(cell, index)
            except CellExecutionError as exc:
                source = cell.source if len(cell.source) < 800 else cell.source[:800] + " ..."
                pytest.fail(f"{path.name}: cell {index} failed:\n{source}\n\n{exc}",
                            pytrace=False)
            loud = [b for text in _texts(cell) for b in BANNERS if b in text]
            assert not loud, f"{path.name}: cell {index} prints third-party banners {loud}"
