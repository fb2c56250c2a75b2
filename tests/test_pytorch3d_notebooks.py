"""PyTorch3D's six tutorial notebooks, run cell by cell with only their imports changed.

The notebooks are PyTorch3D's (``docs/tutorials/*.ipynb`` of facebookresearch/pytorch3d), not
geofit's, so they are not in this repository: point ``GEOFIT_PYTORCH3D_TUTORIALS`` at a folder
holding them (``.ipynb``, or ``.py`` files with ``# %%`` cell markers) and this test ports and
runs each one, as a PyTorch3D user would:

* imports: ``torch`` -> ``geofit.pytorch3d.torch``, ``pytorch3d`` -> ``geofit.pytorch3d``, the
  tutorials' helper files (``utils/generate_cow_renders.py``, ``utils/plot_image_grid.py``) ->
  :mod:`geofit.pytorch3d.tutorial_utils`;
* shell lines (``!wget ...``) and IPython magics (``%matplotlib``) are dropped (the data is
  written beforehand: geofit's dolphin and cow, or their procedural stand-ins, and a coloured
  point cloud for the points tutorial);
* sizes reduced (:data:`REDUCE`: iteration counts, image sizes, views, samples);

then every code cell must run (the points tutorial's pulsar cell must raise geofit's
NotImplementedError naming what to use instead) and each training loop must lower its loss.
Without the folder the test is skipped.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

ENV = "GEOFIT_PYTORCH3D_TUTORIALS"

#: Per tutorial: (pattern, replacement) applied to the code, sizes only.
REDUCE = {
    "deform_source_mesh_to_target_mesh": [(r"\bNiter = 2000\b", "Niter = 40")],
    "render_textured_meshes": [(r"image_size=512", "image_size=64"),
                               (r"\bbatch_size = 20\b", "batch_size = 4")],
    "render_colored_points": [(r"image_size=512", "image_size=64")],
    "fit_textured_mesh": [(r"\bnum_views = 20\b", "num_views = 6"),
                          (r"image_size=128", "image_size=48"),
                          (r"\bNiter = 2000\b", "Niter = 12")],
    "fit_textured_volume": [(r"generate_cow_renders\(num_views=40\)",
                             "generate_cow_renders(num_views=8, image_size=32)"),
                            (r"n_pts_per_ray=150", "n_pts_per_ray=40"),
                            (r"\bvolume_size = 128\b", "volume_size = 24"),
                            (r"\bbatch_size = 10\b", "batch_size = 4"),
                            (r"\bn_iter = 300\b", "n_iter = 12"),
                            (r"n_frames=7\*4", "n_frames=2")],
    "fit_simple_neural_radiance_field": [
        (r"generate_cow_renders\(num_views=40, azimuth_range=180\)",
         "generate_cow_renders(num_views=8, azimuth_range=180, image_size=16)"),
        (r"n_pts_per_ray=128", "n_pts_per_ray=24"),
        (r"n_rays_per_image=750", "n_rays_per_image=64"),
        (r"\bbatch_size = 6\b", "batch_size = 3"),
        (r"\bn_iter = 3000\b", "n_iter = 40"),
        (r"n_frames=3\*5", "n_frames=2")],
}

#: Per tutorial: the loss histories (names in the notebook's namespace) that must go down.
LOSSES = {
    "deform_source_mesh_to_target_mesh": ["chamfer_losses"],
    "fit_textured_mesh": ['losses["silhouette"]["values"]'],
    "fit_textured_volume": [],  # checked through the re-rendered loss below
    "fit_simple_neural_radiance_field": ["loss_history_sil"],
}

_IMPORTS = [
    (r"^(\s*)import torch\.nn\.functional as (\w+)",
     r"\1import geofit.pytorch3d.torch.nn.functional as \2"),
    (r"^(\s*)import torch\s*$", r"\1import geofit.pytorch3d.torch as torch"),
    (r"^(\s*)import pytorch3d\s*$", r"\1import geofit.pytorch3d as pytorch3d"),
    (r"^(\s*)from pytorch3d\.", r"\1from geofit.pytorch3d."),
    (r"^(\s*)from (?:utils\.)?(?:generate_cow_renders|plot_image_grid) import",
     r"\1from geofit.pytorch3d.tutorial_utils import"),
    (r"^(\s*)from utils import", r"\1from geofit.pytorch3d.tutorial_utils import"),
]


def port(source: str, reductions=()) -> str:
    """The cell's code with the imports changed, shell lines and magics dropped, sizes cut."""
    lines = []
    for line in source.splitlines():  # lines of the cell
        stripped = line.lstrip()
        if stripped.startswith(("!", "%")):
            line = line[:len(line) - len(stripped)] + "pass"
        for pattern, repl in _IMPORTS:
            line = re.sub(pattern, repl, line)
        lines.append(line)
    code = "\n".join(lines)
    for pattern, repl in reductions:
        code = re.sub(pattern, repl, code)
    return code


def code_cells(path: Path) -> list[str]:
    """The code cells of a notebook (``.ipynb``) or of a ``# %%`` script."""
    if path.suffix == ".ipynb":
        nb = json.loads(path.read_text(encoding="utf-8"))
        return ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]
    return [c for c in re.split(r"^# %%.*$", path.read_text(encoding="utf-8"), flags=re.M)
            if c.strip()]


def _write_data(root: Path) -> None:
    """The files the tutorials download: dolphin, cow, a coloured point cloud."""
    import geofit
    from geofit import data

    (root / "data" / "cow_mesh").mkdir(parents=True)
    (root / "data" / "PittsburghBridge").mkdir(parents=True)
    dolphin, cow = data.find("dolphin/dolphin.obj"), data.find("cow_mesh/cow.obj")
    if dolphin is not None:
        shutil.copy(dolphin, root / "dolphin.obj")
    else:
        geofit.save_obj(root / "dolphin.obj", data.procedural_target())
    if cow is not None:
        for name in ("cow.obj", "cow.mtl", "cow_texture.png"):  # the three cow files
            shutil.copy(cow.parent / name, root / "data" / "cow_mesh" / name)
    else:
        geofit.save_obj(root / "data" / "cow_mesh" / "cow.obj",
                        data.procedural_textured_mesh(16, 32, 128))
    mesh = geofit.load_mesh(root / "data" / "cow_mesh" / "cow.obj").normalize().mesh
    pts = np.asarray(geofit.sample_points_from_meshes(mesh, 20_000, seed=0))
    rgb = np.abs(pts) / np.abs(pts).max()
    np.savez(root / "data" / "PittsburghBridge" / "pointcloud.npz", verts=pts * 3.0, rgb=rgb)


def _notebooks():
    folder = os.environ.get(ENV)
    if not folder:
        return []
    found = []
    for name in REDUCE:  # the six tutorials
        for ext in (".ipynb", ".py"):
            if (Path(folder) / (name + ext)).exists():
                found.append(Path(folder) / (name + ext))
                break
    return found


def _history(ns: dict, expr: str) -> list:
    return list(eval(expr, {}, ns))  # noqa: S307 - an expression from LOSSES above


@pytest.mark.skipif(not os.environ.get(ENV), reason=f"{ENV} is not set (PyTorch3D's tutorial "
                    f"notebooks are not part of this repository)")
@pytest.mark.parametrize("path", _notebooks(), ids=lambda p: p.stem)
def test_pytorch3d_tutorial_runs_with_only_its_imports_changed(path, tmp_path, monkeypatch):
    """Every code cell runs; the pulsar cell raises NotImplementedError with its hint; the
    training loops lower their losses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import plotly.basedatatypes

    monkeypatch.setattr(plotly.basedatatypes.BaseFigure, "show", lambda self, *a, **k: None)
    monkeypatch.delenv("GEOFIT_QUICK", raising=False)
    _write_data(tmp_path)
    monkeypatch.chdir(tmp_path)
    ns: dict = {"__name__": "__main__"}
    failed = []
    for index, cell in enumerate(code_cells(path)):  # cells, in order, as Jupyter runs them
        code = port(cell, REDUCE[path.stem])
        try:
            with warnings.catch_warnings():
                # fig.show() on the Agg backend, tqdm.notebook outside Jupyter: not geofit's
                warnings.simplefilter("ignore")
                exec(compile(code, f"{path.stem}[{index}]", "exec"), ns)  # noqa: S102
        except NotImplementedError as exc:
            if "PulsarPointsRenderer" not in code or "PointsRenderer" not in str(exc):
                failed.append((index, f"NotImplementedError: {exc}"))
        except Exception as exc:  # noqa: BLE001 - report every failing cell at once
            failed.append((index, f"{type(exc).__name__}: {exc}"))
        finally:
            plt.close("all")
    assert not failed, f"{path.stem}: cells failed: {failed}"
    for expr in LOSSES.get(path.stem, []):  # the loops' recorded losses
        h = _history(ns, expr)
        q = max(len(h) // 4, 1)  # first and last quarters: the Monte Carlo losses are noisy
        assert len(h) >= 4 and np.mean(h[-q:]) < np.mean(h[:q]), (expr, h)
