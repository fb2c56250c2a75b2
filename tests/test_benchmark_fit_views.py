"""benchmarks/fit_views.py at CI size: the test-shape table and the stability table run, write
their JSON, markdown and charts, never report NaN, and flag exactly the alternatives that beat
the default by more than the measured run-to-run noise."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "fit_views.py"


def _run(tmp_path, *args):
    env = dict(os.environ, MPLBACKEND="Agg")
    env.pop("GEOFIT_DATA", None)  # procedural shapes only: the suite does not need the data
    p = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--out", str(tmp_path), *args],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]
    return p.stdout


@pytest.mark.slow
def test_shapes_table_quick(tmp_path):
    """Default twice (the noise) and one alternative on the torus: every figure finite, the
    genus of the target reported, a chart, and flags that follow the noise rule."""
    _run(tmp_path, "--shapes", "torus", "--compare", "best", "--seeds", "2",
         "--noise-shapes", "torus")
    d = json.loads((tmp_path / "fit_views_shapes.json").read_text())
    names = [m["name"] for m in d["methods"]]
    assert names == ["torus:default", "torus:default:seed1", "torus:best"]
    for m in d["methods"]:
        f = m["final"]
        for k in ("iou", "fscore@0.01", "chamfer_l2", "psnr", "seconds"):
            assert isinstance(f[k], float) and math.isfinite(f[k]), (m["name"], k, f[k])
        assert 0.0 <= f["iou"] <= 1.0 and f["n_verts"] > 0 and f["init"]
    noise = d["tables"]["noise"]["torus"]
    default, best = d["methods"][0]["final"], d["methods"][2]["final"]
    beats = best["iou"] - default["iou"] > noise["iou"]
    assert any(s.startswith("torus:best") and "iou" in s for s in d["tables"]["flags"]) == beats
    md = (tmp_path / "fit_views_shapes.md").read_text()
    assert "| torus | default | " in md and "| 1 / " in md  # genus of the torus: 1
    assert "nan" not in md.lower()
    assert (tmp_path / "fit_views_shapes_torus.png").stat().st_size > 1000
    # a run cut short: the table is rebuilt from the JSON alone, the same
    (tmp_path / "fit_views_shapes.md").unlink()
    _run(tmp_path, "--resummarise", str(tmp_path / "fit_views_shapes.json"))
    assert (tmp_path / "fit_views_shapes.md").read_text().split("## Medians")[0] \
        .split("Command:")[1].split("\n", 1)[1] == md.split("## Medians")[0].split(
            "Command:")[1].split("\n", 1)[1]


@pytest.mark.slow
def test_stability_table_quick_on_a_test_shape(tmp_path):
    """The stability table runs on a procedural test shape (genus 1), never NaN."""
    _run(tmp_path, "--stability", "--shapes", "torus", "--only", "default",
         "--cases", "noisy,off_centre")
    d = json.loads((tmp_path / "fit_views_stability.json").read_text())
    rows = d["tables"]["stability"]
    assert [(r["shape"], r["case"]) for r in rows] == [("torus", "noisy"), ("torus", "off_centre")]
    assert all(r["all_steps_finite"] and r["mesh_finite"] and r["metrics_finite"] for r in rows)
    md = (tmp_path / "fit_views_stability.md").read_text()
    assert "## torus" in md and "NON-FINITE" not in md and "nan" not in md.lower()


def test_unknown_shape_is_refused(tmp_path):
    """A shape the benchmark does not know stops it with a message naming the known ones."""
    env = dict(os.environ, MPLBACKEND="Agg")
    p = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--out", str(tmp_path),
                        "--shapes", "no_such_shape"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode != 0 and "no_such_shape" in p.stderr and "torus" in p.stderr
