"""benchmarks/before_after.py: the verdicts it gives, the before tree it accepts, and one real case
run with the same tree on both sides (each fit in a fresh process must then be identical)."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "before_after.py"


def _module():
    spec = importlib.util.spec_from_file_location("before_after", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_compare_names_every_field_that_differs():
    """Equal records are identical; a changed value or a missing field is named; a failed
    child is an error, never identical."""
    ba = _module()
    a = {"result": {"loss_hash": "x", "iou": 0.9, "n_verts": 10}}
    assert ba.compare(a, json.loads(json.dumps(a))) == {"verdict": "identical", "differs": []}
    b = {"result": {"loss_hash": "y", "iou": 0.9}}
    assert ba.compare(a, b) == {"verdict": "differs", "differs": ["loss_hash", "n_verts"]}
    assert ba.compare(a, {"error": "Traceback ..."})["verdict"] == "error"


def test_before_tree_refuses_a_folder_without_geofit(tmp_path):
    """--before-tree pointing at a non-empty folder with no geofit/ stops with its name (and
    makes no git worktree there)."""
    (tmp_path / "something.txt").write_text("not a checkout")
    with pytest.raises(SystemExit, match="holds no geofit"):
        _module().before_tree(str(tmp_path), "cf676f5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["something.txt"]


@pytest.mark.slow
def test_same_tree_both_sides_is_identical(tmp_path):
    """This tree as both "before" and "after" (side by side, --jobs 2): the torus' default
    fit_mesh is identical in the two processes, each imported geofit from the tree, and the
    JSON and markdown are written; ``--merge`` carries the cases into another table."""
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, str(SCRIPT), "--before-tree", str(ROOT), "--cases",
                        "mesh:torus", "--jobs", "2", "--out", str(tmp_path)],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]
    d = json.loads((tmp_path / "before_after.json").read_text())
    assert d["benchmark"] == "before_after"
    case = d["tables"]["identity"]["cases"]["mesh:torus"]
    assert case["compare"] == {"verdict": "identical", "differs": []}
    for side in ("before", "after"):
        assert Path(case[side]["geofit_file"]).resolve().is_relative_to(ROOT)
        r = case[side]["result"]
        assert r["n_verts"] > 0 and 0.0 < r["fscore@0.01"] <= 1.0 and r["n_loss"] > 0
    md = (tmp_path / "before_after.md").read_text()
    assert "**1 of 1 cases identical**" in md and "| mesh:torus | identical |" in md
    # --merge alone runs nothing and takes that run's cases, naming its command
    merged = tmp_path / "merged"
    p = subprocess.run([sys.executable, str(SCRIPT), "--before-tree", str(ROOT), "--merge",
                        str(tmp_path / "before_after.json"), "--out", str(merged)],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-4000:]
    m = json.loads((merged / "before_after.json").read_text())["tables"]["identity"]
    assert m["cases"] == d["tables"]["identity"]["cases"]
    assert "--cases mesh:torus" in m["command"]
