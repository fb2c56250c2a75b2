"""report.html in a real browser: headless Chromium loads it from disk and every image decodes.

The report carries a small script that, after the window's load event, writes into
``#image-check`` how many images decoded (``naturalWidth > 0``) out of how many, and which did
not. Chromium dumps the DOM after running it. Skipped where Debian's ``chromium`` is not
installed (``apt-get install chromium``).
"""
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from geofit.report import write_report
from geofit.tutorials import StepResult, run_tutorials
from geofit.viz import Series, image_panel, plot_accuracy_vs_time, save_png

CHROMIUM = shutil.which("chromium")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (apt-get install chromium)")


class _Imgs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.n = 0

    def handle_starttag(self, tag, attrs):
        self.n += tag == "img"


def _count_imgs(path: Path) -> int:
    p = _Imgs()
    p.feed(path.read_text(encoding="utf-8"))
    return p.n


def _browser_check(html: Path, profile: Path) -> dict:
    """Open ``html`` in headless Chromium; return the #image-check attributes it wrote."""
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", "--disable-dev-shm-usage", f"--user-data-dir={profile}",
           "--virtual-time-budget=10000", "--dump-dom", html.resolve().as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    m = re.search(r'<p id="image-check"([^>]*)>', proc.stdout)
    assert m, (f"chromium returned {proc.returncode} without the report's DOM; "
               f"stderr tail: {proc.stderr[-2000:]}")
    attrs = dict(re.findall(r'(data-[a-z]+)="([^"]*)"', m.group(1)))
    assert attrs.get("data-total"), "the page's load script did not run"
    return {"loaded": int(attrs["data-loaded"]), "total": int(attrs["data-total"]),
            "broken": attrs.get("data-broken", "").split()}


def _synthetic_report(out: Path) -> Path:
    rng = np.random.default_rng(0)
    steps = []
    for name in ("one", "two"):  # two workflows
        d = out / name
        img = rng.random((16, 16, 3))
        res = StepResult(name, name, "tutorial", seconds=1.0)
        res.targets["target"] = save_png(img, d / "target.png")
        res.comparison = image_panel([[img, 1 - img]], d / "comparison.png",
                                     col_labels=["target", "result"])
        res.charts["speed and accuracy"] = plot_accuracy_vs_time(
            [Series("m", [0.1, 1.0], {"e": [1.0, 0.1]})], [{"metric": "e", "logy": True}],
            d / "chart.png")
        steps.append(res)
    return write_report(steps, out, command="test", size="tiny")["html"]


def test_every_image_of_a_report_loads_in_chromium(tmp_path):
    html = _synthetic_report(tmp_path / "out")
    n = _count_imgs(html)
    assert n == 4
    got = _browser_check(html, tmp_path / "profile")
    assert got == {"loaded": n, "total": n, "broken": []}


def test_the_browser_check_sees_a_missing_image(tmp_path):
    """Negative control: with one PNG deleted, the page reports exactly that image as broken."""
    html = _synthetic_report(tmp_path / "out")
    (tmp_path / "out" / "two" / "chart.png").unlink()
    got = _browser_check(html, tmp_path / "profile")
    assert got["total"] == 4 and got["loaded"] == 3
    assert got["broken"] == ["two/chart.png"]


def test_the_command_report_loads_in_chromium(tmp_path, monkeypatch):
    """The report `geofit tutorials` writes (render steps, tiny size, procedural data)."""
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "no-data-here"))
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")  # not the cow installed with geofit
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    run = run_tutorials(tmp_path / "out", size="tiny", only=["render_mesh", "render_points"],
                        progress=False)
    assert run.ok
    n = _count_imgs(run.report["html"])
    assert n == 4  # per step: targets-and-results panel, speed-accuracy chart
    got = _browser_check(run.report["html"], tmp_path / "profile")
    assert got == {"loaded": n, "total": n, "broken": []}
