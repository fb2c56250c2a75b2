"""`geofit tutorials`: the six-step runner, its report (HTML, Markdown, JSON), figure helpers.

The fast tests run the two rendering steps at the tiny size through the command line and check
the report's structure (every <img> exists and decodes); the fitting steps run at the tiny size
under the `slow` marker. All runs use geofit's procedural data (GEOFIT_DATA points to an empty
folder), so they never read the tutorial files.
"""
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from geofit import tutorials
from geofit.cli import build_parser, main
from geofit.fit.history import STATUSES
from geofit.report import format_value, markdown_table, write_report
from geofit.tutorials import STEPS, StepResult, run_step, run_tutorials
from geofit.viz import (
    Series,
    image_panel,
    plot_accuracy_vs_time,
    plot_model_sizes,
    save_png,
    to_uint8,
)


@pytest.fixture
def procedural(tmp_path, monkeypatch):
    """No tutorial files: every step uses geofit's procedural stand-ins."""
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "no-data-here"))
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")  # not the cow installed with geofit
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("MPLBACKEND", "Agg")


class _Images(HTMLParser):
    def __init__(self):
        super().__init__()
        self.srcs, self.ids, self.links = [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.srcs.append(a.get("src"))
        if "id" in a:
            self.ids.append(a["id"])
        if tag == "a":
            self.links.append(a.get("href"))


def _parse(html_path: Path) -> _Images:
    p = _Images()
    p.feed(html_path.read_text(encoding="utf-8"))
    return p


def _check_decodes(path: Path) -> tuple[int, int]:
    with Image.open(path) as im:
        im.load()
        assert im.size[0] > 0 and im.size[1] > 0
        return im.size


def _check_report(out: Path, names) -> dict:
    """Every <img> of report.html and every image link of report.md exists and decodes."""
    html_path = out / "report.html"
    page = _parse(html_path)
    assert page.srcs, "report.html has no images"
    for src in page.srcs:
        assert src and not src.startswith(("/", "http", "data:")), src  # relative files
        _check_decodes(out / src)
    for href in page.links:
        assert (out / href).exists(), href
    for n in names:
        assert n in page.ids, f"no section for {n}"
    assert "image-check" in page.ids
    md = (out / "report.md").read_text(encoding="utf-8")
    md_imgs = [line.split("](", 1)[1].rstrip(")") for line in md.splitlines()
               if line.startswith("![")]
    assert sorted(set(md_imgs)) == sorted(set(page.srcs))
    data = json.loads((out / "report.json").read_text(encoding="utf-8"))
    assert data["schema"] == "geofit-benchmark/1"
    assert [s["name"] for s in data["tables"]["steps"]] == list(names)
    return data


# ------------------------------------------------------------------------------ command line
def test_parser_lists_tutorials():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert "tutorials" in sub.choices


def test_cli_render_steps_write_a_complete_report(tmp_path, procedural, capsys):
    """`geofit tutorials --only render_mesh,render_points` writes images, charts and a report
    whose every image exists and decodes."""
    out = tmp_path / "out"
    gallery = tmp_path / "docs"
    rc = main(["tutorials", "--out", str(out), "--size", "tiny", "--no-progress",
               "--only", "render_mesh,render_points", "--gallery", str(gallery)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "2 of 2 workflows ran" in text and "gallery of 4 images" in text
    listed = (gallery / "README.md").read_text()
    assert "geofit tutorials --out" in listed and "--gallery" in listed
    assert "Data folder" in listed and "procedural" in listed  # says which data was used
    for name in ("render_mesh_results", "render_mesh_speed_accuracy", "render_points_results",
                 "render_points_speed_accuracy"):
        assert f"]({name}.png)" in listed
        _check_decodes(gallery / f"{name}.png")
    data = _check_report(out, ["render_mesh", "render_points"])
    steps = {s["name"]: s for s in data["tables"]["steps"]}
    for s in steps.values():
        assert s["status"] == "ok"
        assert s["comparison"] and s["charts"] and s["stability"] and s["param_counts"]
    # the real content: antialiasing lowers the error to the supersampled reference ...
    rm = [r for r in steps["render_mesh"]["metrics"] if "rays per pixel" in r]
    for size in {r["image"] for r in rm}:
        err = [r["mean |RGB - reference|"] for r in rm if r["image"] == size]
        assert err[1] < err[0]
    # ... and more points cover more of the mesh's silhouette at a fixed radius
    rp = [r for r in steps["render_points"]["metrics"] if "silhouette IoU vs mesh" in r]
    for radius in {r["radius"] for r in rp}:
        iou = [r["silhouette IoU vs mesh"] for r in rp if r["radius"] == radius]
        assert iou[-1] > iou[0]
    # where rendering breaks: bad input is refused with a message, never a NaN image
    rows = steps["render_mesh"]["stability"]
    nan_row = next(r for r in rows if r["case"] == "NaN vertex")
    assert nan_row["outcome"].startswith("failed: ValueError: ") and "verts" in nan_row["outcome"]
    assert all("finite=False" not in r["outcome"] for r in rows)
    # the comparison panel is wider than one tile: targets next to results
    w, h = _check_decodes(out / steps["render_points"]["comparison"])
    assert w > 3 * h


def test_failed_step_is_reported_not_dropped(tmp_path, procedural, monkeypatch, capsys):
    """A step that raises shows up as 'failed: <exception>: <message>' with its traceback, and
    the command exits with 1."""
    def boom(out, size="default", *, progress=True, seed=0):
        raise RuntimeError("the workflow is not ready")

    title, tut = STEPS["nerf"][1:]
    monkeypatch.setitem(tutorials.STEPS, "nerf", (boom, title, tut))
    out = tmp_path / "out"
    rc = main(["tutorials", "--out", str(out), "--size", "tiny", "--no-progress",
               "--only", "render_mesh,nerf"])
    assert rc == 1
    data = _check_report(out, ["render_mesh", "nerf"])
    nerf = data["tables"]["steps"][1]
    assert nerf["status"] == "failed: RuntimeError: the workflow is not ready"
    assert "RuntimeError" in (out / nerf["files"]["traceback"]).read_text()
    html = (out / "report.html").read_text()
    assert "failed: RuntimeError: the workflow is not ready" in html
    assert "1 of 2 workflows ran" in capsys.readouterr().out


@pytest.mark.parametrize("argv, match", [
    (["--only", "nope"], "unknown step"),
    (["--only", ","], "unknown step"),
    (["--full", "--size", "tiny"], "contradict"),
])
def test_cli_rejects_bad_options(tmp_path, argv, match, capsys):
    assert main(["tutorials", "--out", str(tmp_path), "--no-progress"] + argv) == 1
    assert match in capsys.readouterr().err


@pytest.mark.parametrize("kw, match", [
    ({"size": "huge"}, "size"),
    ({"only": []}, "only"),
    ({"only": ["render_mesh", "bogus"]}, "only"),
])
def test_run_tutorials_validation(tmp_path, kw, match):
    with pytest.raises(ValueError, match=match):
        run_tutorials(tmp_path, progress=False, **kw)


@pytest.mark.parametrize("kw, match", [({"name": "nope"}, "name"), ({"size": "xl"}, "size")])
def test_run_step_validation(tmp_path, kw, match):
    args = {"name": "render_mesh", "size": "tiny"} | kw
    with pytest.raises(ValueError, match=match):
        run_step(args["name"], tmp_path, args["size"], progress=False)


# ------------------------------------------------------------------------------ every step
def _check_step(res: StepResult, out: Path):
    assert res.ok, res.status
    assert res.comparison is not None and res.comparison.parent.parent == out
    _check_decodes(res.comparison)
    assert res.charts
    for p in list(res.charts.values()) + list(res.images.values()) + list(res.targets.values()):
        _check_decodes(p)
    assert res.metrics and res.param_counts and res.stability
    for m in res.methods:
        n = len(m["curve"]["seconds"])
        assert all(len(v) == n for v in m["curve"].values())
        assert np.all(np.diff(m["curve"]["seconds"]) >= 0) or m["name"].endswith("px") \
            or m["name"].startswith("r")  # render sweeps are not time series
    for f in res.files.values():
        assert Path(f).exists()
    for row in res.stability:
        assert row["outcome"].startswith(("ok", "converged", "stopped: ", "failed: "))
        for k in ("NaN vertices", "NaN in volume", "NaN weights"):
            assert row.get(k) in (None, False), row  # never NaN results


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fit_mesh", "fit_views", "fit_volume", "nerf"])
def test_fitting_steps_run_at_tiny_size(tmp_path, procedural, name):
    """Each fitting step runs PyTorch3D's recipe and geofit's method and records both."""
    res = run_step(name, tmp_path, "tiny", progress=False)
    _check_step(res, tmp_path)
    names = [m["name"] for m in res.methods]
    assert names[0] == "tutorial" and len(names) >= 2
    for m in res.methods:
        assert m["final"]["n_params"] > 0
        assert m["status"] in STATUSES
    # the tiny size cuts PyTorch3D's recipe: the row and the summary say so, not only the settings
    from geofit.tutorials.shared import P3D_COLUMN

    assert "(recipe cut to " in res.metrics[0]["method"]
    assert "(recipe cut to " in res.headline[P3D_COLUMN]
    assert all("(recipe cut to " not in r["method"] for r in res.metrics[1:])
    if name == "fit_mesh":
        from geofit.io import load_mesh

        for n in names:
            mesh = load_mesh(res.files[f"{n} mesh"])
            assert mesh.n_verts == res.methods[names.index(n)]["final"]["n_verts"]
        nan_rows = [r for r in res.stability if r["case"] == "NaN in the target"]
        assert nan_rows and all(r["outcome"].startswith("failed: ValueError") for r in nan_rows)
    if name == "fit_volume":
        for n in names:
            with np.load(res.files[f"{n} volume"]) as z:
                assert np.isfinite(z["densities"]).all() and z["features"].shape[0] == 3


def test_render_points_adds_the_tutorial_cloud_when_found(tmp_path, procedural):
    """With PittsburghBridge/pointcloud.npz in the data folder, its three renders are added
    as a second row of the comparison."""
    res0 = run_step("render_points", tmp_path / "a", "tiny", progress=False)
    _check_step(res0, tmp_path / "a")
    counts = {r["model"]: r["count"] for r in res0.param_counts}
    assert counts["cloud: colour values"] == 3 * counts["cloud: points"]
    bridge = tmp_path / "no-data-here" / "PittsburghBridge"
    bridge.mkdir(parents=True)
    rng = np.random.default_rng(1)
    np.savez(bridge / "pointcloud.npz", verts=rng.uniform(-3, 3, (2000, 3)),
             rgb=rng.random((2000, 3)))
    res1 = run_step("render_points", tmp_path / "b", "tiny", progress=False)
    _check_step(res1, tmp_path / "b")
    assert [k for k in res1.images if k.startswith("PittsburghBridge")] == [
        f"PittsburghBridge render {i}" for i in (1, 2, 3)]
    blue = np.asarray(Image.open(res1.images["PittsburghBridge render 2"]))
    assert (blue[..., 2] == 255).mean() > 0.2  # the tutorial's blue background shows
    h0 = _check_decodes(res0.comparison)[1]
    h1 = _check_decodes(res1.comparison)[1]
    assert h1 - h0 >= 128 + 4  # one more row of tiles (tile >= 128 px, pad 4)
    assert any("PittsburghBridge" in n for n in res1.notes)


# ------------------------------------------------------------------------------ report
def _fake_step(out: Path, name: str, status: str = "ok") -> StepResult:
    d = out / name
    img = np.zeros((8, 8, 3))
    img[..., 0] = 1.0
    res = StepResult(name, name.title(), "some_tutorial", status=status, seconds=1.5)
    if status == "ok":
        res.targets["t"] = save_png(img, d / "t.png")
        res.comparison = image_panel([[img, img]], d / "c.png", col_labels=["a", "b"])
        res.charts["chart | with a bar"] = plot_accuracy_vs_time(
            [Series("m", [0.1, 0.2], {"e": [1.0, 0.5]})], [{"metric": "e", "logy": True}],
            d / "chart.png")
        res.metrics = [{"method": "m", "seconds": 0.2, "e": 0.5}]
        res.stability = [{"case": "bad | input", "outcome": "failed: ValueError: x"}]
        res.methods = [{"name": "tutorial", "label": "m", "status": "ok", "message": "",
                        "config": {}, "final": {"n_params": 10},
                        "curve": {"seconds": [0.1, 0.2], "e": [1.0, 0.5]}}]
    return res


def test_write_report_structure(tmp_path):
    steps = [_fake_step(tmp_path, "alpha"), _fake_step(tmp_path, "beta", "failed: X: y")]
    files = write_report(steps, tmp_path, command="geofit tutorials", size="tiny", seconds=3.0)
    data = _check_report(tmp_path, ["alpha", "beta"])
    assert set(files) == {"html", "md", "json"}
    assert len(_parse(files["html"]).srcs) == 2  # comparison and chart of the one ok step
    md = files["md"].read_text()
    assert "bad \\| input" in md and "failed: X: y" in md  # pipes escaped in tables
    assert data["methods"][0]["step"] == "alpha"
    assert data["tables"]["steps"][1]["status"] == "failed: X: y"


def test_recipe_cut_marks_only_a_shortened_baseline():
    from geofit.tutorials.shared import recipe_cut

    assert recipe_cut(300, 2000) == " (recipe cut to 300 of 2000 steps)"
    assert recipe_cut(256, 512, "px per side") == " (recipe cut to 256 of 512 px per side)"
    assert recipe_cut(2000, 2000) == "" and recipe_cut(2500, 2000) == ""
    assert recipe_cut(None, 2000) == ""


def test_format_value_and_markdown_table():
    assert format_value(float("nan")) == "nan" and format_value(-float("inf")) == "-inf"
    assert format_value(True) == "yes" and format_value(12345678.0) == "1.235e+07"
    assert format_value(np.int64(1000)) == "1,000" and format_value(0.0) == "0"
    t = markdown_table([{"a": "x|y"}], ["a", "b"])
    assert t.splitlines()[2] == "| x\\|y |  |"
    assert markdown_table([]) == ""


# ------------------------------------------------------------------------------ figures
def test_to_uint8_rounds_clips_and_zeroes_nan():
    out = to_uint8(np.array([[[-1.0], [0.5], [np.nan], [2.0]]]))
    assert out.dtype == np.uint8 and out.tolist() == [[0, 128, 0, 255]]
    with pytest.raises(ValueError, match="image"):
        to_uint8(np.zeros((2, 2, 2)))


def test_image_panel_places_each_image_in_its_cell(tmp_path):
    red = np.zeros((10, 10, 3))
    red[..., 0] = 1.0
    blue = np.zeros((10, 10))  # grey-scale: black
    p = image_panel([[red, None], [None, blue]], tmp_path / "p.png", tile=20, pad=2)
    a = np.asarray(Image.open(p))
    assert a.shape == (2 * 20 + 3 * 2, 2 * 20 + 3 * 2, 3)
    assert a[2 + 10, 2 + 10].tolist() == [255, 0, 0]          # row 0, column 0: red
    assert a[2 + 10, 24 + 10].tolist() == [255, 255, 255]     # empty cell: background
    assert a[24 + 10, 24 + 10].tolist() == [0, 0, 0]          # row 1, column 1: black
    labelled = image_panel([[red]], tmp_path / "q.png", col_labels=["a long label"],
                           row_labels=["row"])
    b = np.asarray(Image.open(labelled))
    assert b.shape[0] > 128 and b.shape[1] > 128 and (b < 128).any()  # text drawn


@pytest.mark.parametrize("kw, match", [
    ({"rows": []}, "rows"),
    ({"rows": [[None]]}, "rows"),
    ({"col_labels": ["a", "b"]}, "col_labels"),
    ({"row_labels": ["a", "b"]}, "row_labels"),
    ({"rows": [[np.zeros((4, 4, 2))]]}, "images"),
    ({"tile": 0}, "tile"),
])
def test_image_panel_validation(tmp_path, kw, match):
    args = {"rows": [[np.zeros((4, 4, 3))]]} | kw
    rows = args.pop("rows")
    with pytest.raises(ValueError, match=match):
        image_panel(rows, tmp_path / "x.png", **args)


def test_plot_accuracy_vs_time_writes_a_png_even_with_bad_values(tmp_path):
    runs = [Series("a", [0.0, 1.0, 2.0], {"e": [0.0, np.inf, 0.1], "f": [1, 2, 3]}),
            Series("b", [], {"e": []})]
    p = plot_accuracy_vs_time(runs, [{"metric": "e", "logy": True, "target": 0.05},
                                     {"metric": "f", "label": "f"}],
                              tmp_path / "c.png", title="t", time_limit=1.5,
                              reference_points=[{"seconds": 1.0, "e": 0.2, "label": "ref"}])
    w, h = _check_decodes(p)
    assert w > h > 100


@pytest.mark.parametrize("panels, match", [([], "panels"), ([{"label": "x"}], "metric")])
def test_plot_accuracy_vs_time_validation(tmp_path, panels, match):
    with pytest.raises(ValueError, match=match):
        plot_accuracy_vs_time([], panels, tmp_path / "x.png")


def test_plot_model_sizes(tmp_path):
    p = plot_model_sizes({"tutorial": 317188, "geofit": 20500}, tmp_path / "s.png",
                         highlight=["tutorial"], title="sizes")
    _check_decodes(p)
    for bad, match in (({}, "sizes"), ({"x": 0}, "x"), ({"x": float("nan")}, "x")):
        with pytest.raises(ValueError, match=match):
            plot_model_sizes(bad, tmp_path / "t.png")


def test_fit_mesh_stability_scenarios():
    """The shared stability scenarios perturb exactly one input each; unknown modes raise."""
    from geofit import ico_sphere
    from geofit.tutorials.stability import MESH_MODES, fit_mesh_scenario

    target = ico_sphere(3)
    kw = {"method": "sgd"}
    for mode in MESH_MODES:
        sc = fit_mesh_scenario(mode, target, kw)
        assert kw == {"method": "sgd"}  # the caller's kwargs are not modified
        if mode == "noise":
            d = np.abs(sc.target.verts - target.verts)
            assert 0 < d.max() < 0.1 and sc.target.n_faces == target.n_faces
        elif mode == "holes":
            assert 0 < sc.target.n_faces < target.n_faces
        elif mode == "torus":
            assert sc.reference is sc.target and sc.target.n_verts != target.n_verts
        elif mode == "degenerate_start":
            areas = sc.source.face_areas
            assert np.sum(areas < 1e-12) > 0
        elif mode == "step_x100":
            assert sc.kwargs["lr"] == 100.0
        elif mode == "nan_target":
            assert np.isnan(sc.target[0]).sum() == 1
        assert sc.reference is target or mode == "torus"
    lb = fit_mesh_scenario("step_x100", target, {"method": "lbfgs"})
    assert len(lb.kwargs["weights"]) == 2
    with pytest.raises(ValueError, match="mode"):
        fit_mesh_scenario("flood", target, kw)
