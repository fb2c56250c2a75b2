"""Every figure in benchmarks/results is written by a script of benchmarks/, with its command,
machine and load (no benchmark is run here: the files are read as they are committed)."""
import json
import shlex
from pathlib import Path

import pytest
from _helpers import benchmark_module

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
RESULTS = BENCHMARKS / "results"
JSONS = sorted(RESULTS.rglob("*.json"))
SCRIPTS = {p.name: p for p in BENCHMARKS.rglob("*.py") if "results" not in p.parts}


def _rel(p: Path) -> str:
    return p.relative_to(RESULTS).as_posix()


def _script(command: str) -> str | None:
    """The first ``*.py`` of a command line, as a file name."""
    for token in shlex.split(command):
        if token.endswith(".py"):
            return Path(token).name
    return None


def test_there_are_results_to_check():
    """The glob finds the committed results (a moved folder would make the tests below vacuous)."""
    assert len(JSONS) >= 10


@pytest.mark.parametrize("path", JSONS, ids=_rel)
def test_result_json_has_command_machine_and_load(path):
    """The JSON names the script that wrote it (a file of benchmarks/), the machine and the load,
    and its ``benchmark`` is its file name."""
    d = json.loads(path.read_text(encoding="utf-8"))
    command = d.get("command")
    assert isinstance(command, str) and command, f"{_rel(path)}: no command"
    script = _script(command)
    assert script in SCRIPTS, (f"{_rel(path)}: command {command!r} names no script of "
                               f"benchmarks/ (found {script!r})")
    machine = d.get("machine")
    assert isinstance(machine, dict) and machine.get("cpu"), f"{_rel(path)}: no machine"
    load = d.get("load", machine.get("load_average_1_5_15min"))
    assert load, f"{_rel(path)}: no load (top-level 'load' or machine.load_average_1_5_15min)"
    assert d.get("benchmark") == path.stem, (f"{_rel(path)}: benchmark {d.get('benchmark')!r} "
                                             f"is not the file's name")


@pytest.mark.parametrize("path", sorted(p for p in RESULTS.rglob("*") if p.is_file()
                                        and p.suffix != ".json"), ids=_rel)
def test_every_chart_and_table_belongs_to_a_result_json(path):
    """A PNG or markdown table is named after a result JSON beside it (``fit_volume.png``,
    ``fit_volume_params.png``, ``fit_mesh_shapes_torus.png``): no figure without its numbers."""
    stems = {p.stem for p in path.parent.glob("*.json")}
    assert any(path.stem == s or path.stem.startswith(s + "_") for s in stems), (
        f"{_rel(path)}: no result JSON of its name in {_rel(path.parent) or 'results'}/")


def test_peers_script_skips_cleanly_without_pytorch3d(tmp_path):
    """benchmarks/peers/pytorch3d_tutorials.py exits 0 with a clear message and writes nothing
    when ``import pytorch3d`` fails (forced here by a stub package that raises ImportError)."""
    import os
    import subprocess
    import sys

    stub = tmp_path / "stub" / "pytorch3d"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text("raise ImportError('no pytorch3d here')\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(stub.parent), env.get("PYTHONPATH", "")])
    out = tmp_path / "results"
    proc = subprocess.run([sys.executable, str(BENCHMARKS / "peers" / "pytorch3d_tutorials.py"),
                           "all", "--out", str(out)], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "skipped: PyTorch3D not installed" in proc.stdout
    assert not out.exists() or not any(out.iterdir())


def test_scans_quiet_timings_join_only_the_same_fits(tmp_path):
    """``benchmarks/_scans.py --quiet-timings``: a quiet geofit-only run's wall seconds go
    beside the grid's geofit row only where the quiet fit is the same (faces, chamfer-L2,
    F@0.01 equal), and the verdict's 10 s then uses them."""
    scans = benchmark_module("_scans")
    row = {"shape": "torus", "condition": "noise 0", "factor": "noise", "n_points": 100,
           "faces": 50, "chamfer_l2": 1e-5, "fscore": 0.99, "seconds": 30.0, "cpu_seconds": 8.0,
           "load": 20.0}
    peer = dict(row, method="Poisson (same size)", chamfer_l2=2e-5, fscore=0.98)
    grid = {"benchmark": "g", "command": "c", "load": [20.0, 20.0],
            "rows": [dict(row, method="geofit"), peer,
                     dict(row, method="geofit", shape="teapot"),
                     dict(peer, shape="teapot")]}
    quiet = {"benchmark": "q", "command": "cq", "load": [1.5, 1.9],
             "rows": [dict(row, method="geofit", seconds=4.0, load=1.5),
                      dict(row, method="geofit", shape="teapot", chamfer_l2=1.1e-5,
                           seconds=3.0, load=1.5)]}
    (tmp_path / "g.json").write_text(json.dumps(grid))
    (tmp_path / "q.json").write_text(json.dumps(quiet))
    assert scans.verdicts(grid["rows"])[0]["time"] is False
    assert scans.add_quiet_timings(tmp_path, "g", tmp_path / "q.json") == 1
    rows = json.loads((tmp_path / "g.json").read_text())["rows"]
    assert rows[0]["quiet_seconds"] == 4.0 and "quiet_seconds" not in rows[2]
    v = {x["shape"]: x for x in scans.verdicts(rows)}
    assert v["torus"]["time"] and v["torus"]["pass"] and not v["teapot"]["time"]
