"""The command line runs the API's defaults: each `geofit fit-*` sub-command calls its fit with the
data plus only the options the user gave, and gives the API's result; arguments and paths are
checked before anything heavy is imported; help texts come from the docstrings."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import geofit.fit
from geofit import ico_sphere, save_obj
from geofit.cli import build_parser, main
from geofit.cli import fit_mesh as cli_fit_mesh
from geofit.cli import fit_nerf as cli_fit_nerf
from geofit.cli import fit_views as cli_fit_views
from geofit.cli import fit_volume as cli_fit_volume
from geofit.cli._common import FIT_OPTIONS, api_doc
from geofit.io import load_mesh

FIT_COMMANDS = {"fit-mesh": cli_fit_mesh, "fit-views": cli_fit_views,
                "fit-volume": cli_fit_volume, "fit-nerf": cli_fit_nerf}


@pytest.fixture()
def small_data(monkeypatch, tmp_path):
    """The procedural stand-ins (small) instead of the tutorial files."""
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "nothing-here"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def test_fit_mesh_cli_equals_api(tmp_path):
    """`geofit fit-mesh TARGET --seed 3` writes exactly the vertices of fit_mesh(target, seed=3)
    (a time budget far beyond the fit's needs on both sides: a wall-clock budget that binds
    would make either depend on the machine's load)."""
    from geofit.shapes import torus

    target = tmp_path / "torus.obj"
    save_obj(target, torus(major_radius=1.0, minor_radius=0.4, n_major=12, n_minor=6))
    assert main(["fit-mesh", str(target), "--out", str(tmp_path / "o"), "--seed", "3",
                 "--time-budget", "1e4", "--no-progress"]) == 0
    api = geofit.fit_mesh(load_mesh(target, load_textures=False), seed=3, time_budget=1e4,
                          progress=False)
    assert api.status != "time_budget"
    back = load_mesh(tmp_path / "o" / "fit_mesh.obj")
    np.testing.assert_array_equal(back.faces, api.mesh.faces)
    np.testing.assert_allclose(back.verts, api.mesh.verts, rtol=0, atol=1e-12)
    hist = json.loads((tmp_path / "o" / "fit_mesh_history.json").read_text())
    assert hist["final_metrics"]["fscore@0.01"] == pytest.approx(api.metrics.fscore[0.01])


def test_fit_mesh_cli_on_a_point_cloud_equals_api(tmp_path, monkeypatch):
    """`geofit fit-mesh points.ply --seed 3` writes exactly the mesh of fit_mesh(points,
    seed=3): the same vertices, faces, status and solver counts (no time budget on either
    side: the default stops on its own tests, so its result does not depend on the load).

    Open3D's Poisson reconstruction, the cloud's first mesh, differs from call to call by
    about 1e-6 even on one thread (isl-org/Open3D#2117), so both sides get the first call's
    reconstruction of these points: everything else must agree value for value."""
    import geofit.fit.adaptive as fa
    from geofit.io import load_pointcloud, save_pointcloud
    from geofit.ops import sample_points_from_meshes
    from geofit.shapes import torus
    from geofit.structures import PointCloud

    real, made = fa.mesh_from_points, {}

    def once(cloud, **kw):
        key = cloud.points.tobytes()
        if key not in made:
            made[key] = real(cloud, **kw)
        return made[key]

    monkeypatch.setattr(fa, "mesh_from_points", once)

    pts = sample_points_from_meshes(torus(1.0, 0.4, 24, 12), 3000, seed=1)
    path = tmp_path / "points.ply"
    save_pointcloud(path, PointCloud(pts))
    assert main(["fit-mesh", str(path), "--out", str(tmp_path / "o"), "--seed", "3",
                 "--no-progress"]) == 0
    api = geofit.fit_mesh(load_pointcloud(path).points, seed=3, progress=False)
    back = load_mesh(tmp_path / "o" / "fit_mesh.obj")
    np.testing.assert_array_equal(back.faces, api.mesh.faces)
    np.testing.assert_allclose(back.verts, api.mesh.verts, rtol=0, atol=1e-12)
    hist = json.loads((tmp_path / "o" / "fit_mesh_history.json").read_text())
    assert (hist["status"], hist["n_iterations"], hist["n_evaluations"]) == \
        (api.status, api.n_iterations, api.n_evaluations)
    assert hist["final_loss"] == api.history.loss[-1] and api.status != "time_budget"
    assert len(made) == 1  # one cloud, one reconstruction: both sides fitted the same points


def _nerf_synthetic_folder(root, image_size: int = 32):
    """A tiny NeRF-synthetic split folder rendered by geofit: transforms_{train,val,test}.json
    and {train,val,test}/r_*.png (RGBA, alpha = silhouette), no transforms.json. Returns the
    rendered views."""
    import shutil

    from geofit.datasets import render_views
    from geofit.io import save_views
    from geofit.structures import Mesh, TexturesVertex

    s = ico_sphere(2)
    V = s.verts * np.array([0.8, 0.6, 0.7])
    colors = 0.2 + 0.6 * (0.5 + 0.5 * V / 0.8)
    data = render_views(Mesh(V, s.faces, TexturesVertex(colors)), np.arange(12) * 30.0,
                        np.tile([10.0, 30.0], 6), image_size=image_size)
    root.mkdir()
    for split, sl in (("train", slice(0, 8)), ("val", slice(8, 10)), ("test", slice(10, 12))):
        tmp = root.parent / f"_{split}"
        save_views(tmp, data[sl])
        shutil.copytree(tmp / "images", root / split)
        meta = json.loads((tmp / "transforms.json").read_text())
        for fr in meta["frames"]:
            fr["file_path"] = "./" + fr["file_path"].replace("images/", f"{split}/")[:-4]
        (root / f"transforms_{split}.json").write_text(json.dumps(meta))
    assert not (root / "transforms.json").exists()
    return data


def test_fit_views_cli_on_a_nerf_synthetic_folder_equals_api(tmp_path):
    """`geofit fit-views FOLDER` (a NeRF-synthetic split folder) run as a command fits the
    training views with the test views held out, and writes exactly the mesh and colours of
    fit_mesh_to_views(load_views(FOLDER), seed=2)."""
    from geofit.io import load_views

    root = tmp_path / "blob"
    data = _nerf_synthetic_folder(root)
    out = tmp_path / "o"
    res = subprocess.run([sys.executable, "-m", "geofit", "fit-views", str(root), "--out",
                          str(out), "--seed", "2", "--no-progress"], capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "held-out metrics" in res.stdout
    views = load_views(root)
    assert len(views) == 8 and len(views.held_out) == 2
    np.testing.assert_allclose(views.held_out.images, data.images[10:], atol=0.5 / 255)
    api = geofit.fit_mesh_to_views(views, seed=2, progress=False)
    got = np.load(out / "fit_views_colors.npz")
    np.testing.assert_array_equal(got["faces"], api.mesh.faces)
    np.testing.assert_array_equal(got["verts"], api.mesh.verts)
    np.testing.assert_array_equal(got["colors"], api.colors)
    summary = json.loads((out / "fit_views.json").read_text())
    assert summary["status"] == api.status and summary["views"] == 8
    assert summary["heldout"] == 2 and summary["n_iterations"] == api.n_iterations


class _Spy:
    """Stands in for a fit: records each call, then runs the real fit briefly (a short time
    budget through the sub-command's own table) so that the command finishes."""

    def __init__(self, real, budget_keyword):
        self.real, self.budget_keyword, self.calls = real, budget_keyword, []

    def __call__(self, data, **kwargs):
        self.calls.append((data, dict(kwargs)))
        return self.real(data, **{**kwargs, self.budget_keyword: 0.5, "progress": False})


def _spy(monkeypatch, name: str, module) -> _Spy:
    spy = _Spy(getattr(geofit.fit, name), FIT_OPTIONS["time_budget"])
    monkeypatch.setattr(geofit.fit, name, spy)
    return spy


def _same_views(a, b) -> None:
    np.testing.assert_array_equal(a.images, b.images)
    np.testing.assert_array_equal(a.silhouettes, b.silhouettes)
    np.testing.assert_array_equal(a.cameras.R, b.cameras.R)
    np.testing.assert_array_equal(a.cameras.T, b.cameras.T)


@pytest.mark.parametrize("command, name, tutorial", [
    ("fit-views", "fit_mesh_to_views", 4),
    ("fit-volume", "fit_volume", 5),
    ("fit-nerf", "fit_nerf", 6),
])
def test_multiview_cli_calls_the_api_default(command, name, tutorial, tmp_path, monkeypatch,
                                             small_data):
    """The sub-command passes the tutorial's views (the same arrays as
    tutorial_views(tutorial, ...)) and only the seed it was given: the fit's own defaults
    decide the rest, so its result is the API's."""
    from geofit.datasets import tutorial_views

    module = FIT_COMMANDS[command]
    spy = _spy(monkeypatch, name, module)
    flags = ["--views", "4", "--image-size", "16", "--heldout", "2"]
    if command != "fit-views":
        flags += ["--frames", "0"]
    assert main([command, "--out", str(tmp_path / "o"), "--seed", "3", *flags]) in (0, 1)
    (data, kwargs), = spy.calls
    assert kwargs == {"seed": 3}
    api = tutorial_views(tutorial, num_views=4, image_size=16, num_held_out=2)
    _same_views(data, api)
    _same_views(data.held_out, api.held_out)
    written = {"fit-views": ("fit_views.obj", "fit_views.json", "fit_views.png",
                             "fit_views_colors.npz"),
               "fit-volume": ("volume_summary.json", "volume.npz", "volume_heldout.png"),
               "fit-nerf": ("nerf_summary.json", "nerf_field.npz")}[command]
    for name in written:
        assert (tmp_path / "o" / name).stat().st_size > 0


@pytest.mark.parametrize("command, name", [("fit-volume", "fit_volume"),
                                           ("fit-views", "fit_mesh_to_views")])
def test_capture_folder_reaches_the_fit(command, name, tmp_path, monkeypatch, small_data):
    """`geofit fit-* CAPTURE` fits the capture's views (every 8th held out), as loaded by
    geofit.io.load_views, with the fit's defaults."""
    from geofit.datasets import tutorial_views
    from geofit.io import load_views, save_views

    save_views(tmp_path / "cap", tutorial_views(5, num_views=9, image_size=16, num_held_out=0))
    spy = _spy(monkeypatch, name, FIT_COMMANDS[command])
    flags = ["--frames", "0"] if command != "fit-views" else []
    assert main([command, str(tmp_path / "cap"), "--out", str(tmp_path / "o"), *flags]) in (0, 1)
    (data, kwargs), = spy.calls
    assert kwargs == {}
    full = load_views(tmp_path / "cap")
    keep = np.arange(9) % 8 != 0
    np.testing.assert_array_equal(data.images, full.images[keep])
    np.testing.assert_array_equal(data.held_out.images, full.images[~keep])


def test_time_budget_and_progress_go_to_the_fit(tmp_path, monkeypatch, small_data):
    """--time-budget and --no-progress reach the fit under its keywords (the table)."""
    spy = _spy(monkeypatch, "fit_volume", cli_fit_volume)
    assert main(["fit-volume", "--out", str(tmp_path), "--views", "4", "--image-size", "16",
                 "--heldout", "2", "--frames", "0", "--time-budget", "7",
                 "--no-progress"]) in (0, 1)
    assert spy.calls[0][1] == {"time_budget": 7.0, "progress": False}


@pytest.mark.parametrize("fmt", ["xyz", "npz", "ply"])
def test_fit_mesh_takes_point_clouds(fmt, tmp_path, monkeypatch):
    """`geofit fit-mesh cloud.{xyz,npz,ply}` hands fit_mesh the points, as the API takes them."""
    from geofit.io import save_pointcloud
    from geofit.ops import sample_points_from_meshes
    from geofit.structures import PointCloud

    pts = sample_points_from_meshes(ico_sphere(2), 300, seed=0)
    path = tmp_path / f"cloud.{fmt}"
    if fmt == "xyz":
        np.savetxt(path, pts)
    else:
        save_pointcloud(path, PointCloud(pts))
    spy = _spy(monkeypatch, "fit_mesh", cli_fit_mesh)
    assert main(["fit-mesh", str(path), "--out", str(tmp_path / "o"), "--no-progress"]) in (0, 1)
    (data, kwargs), = spy.calls
    assert kwargs == {"progress": False}
    got = getattr(data, "points", data)
    np.testing.assert_allclose(got, pts, rtol=0, atol=1e-6)
    assert (tmp_path / "o" / "fit_mesh.obj").stat().st_size > 0


def test_render_cli_equals_api(tmp_path):
    """`geofit render MESH` draws what the renderer draws with the same camera and light."""
    from PIL import Image

    from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    from geofit.render import MeshRasterizer, MeshRenderer, PointLights, \
        RasterizationSettings, SoftPhongShader

    mesh_path = tmp_path / "m.obj"
    save_obj(mesh_path, ico_sphere(2))
    assert main(["render", str(mesh_path), "--image-size", "32", "--out", str(tmp_path)]) == 0
    R, T = look_at_view_transform(2.7, 0.0, 180.0)
    cams = FoVPerspectiveCameras(R=R, T=T)
    img = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=32)),
                       SoftPhongShader(lights=PointLights(location=[[0.0, 0.0, -3.0]])))(
        load_mesh(mesh_path))
    want = (np.clip(img[0, ..., :3], 0, 1) * 255 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "render.png"))[..., :3],
                                  want)


def test_one_option_vocabulary_and_docstring_help():
    """Every fit sub-command has --time-budget (never --time) and --seed, whose help is the
    first sentence of the fit's docstring for that keyword; the command's help is its
    module docstring's first line; no stale text."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, module in FIT_COMMANDS.items():
        p = sub.choices[name]
        flags = {s for a in p._actions for s in a.option_strings}
        assert {"--time-budget", "--seed", "--no-progress"} <= flags and "--time" not in flags
        for action in p._actions:
            if action.dest in FIT_OPTIONS:
                doc = api_doc(module.API, FIT_OPTIONS[action.dest])
                assert doc and action.help.startswith(doc)
        text = p.format_help()
        assert "deforms a sphere" not in text and "target mesh (.obj)" not in text
    for name, choice in sub.choices.items():
        assert sub._choices_actions and choice.description
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert "point cloud" in helps["fit-mesh"]
    for name, module in FIT_COMMANDS.items():
        assert helps[name].strip() and helps[name].split()[0] == "fit"
    assert api_doc(("fit/mesh.py", "fit_mesh"), "time_budget")


def test_api_doc_reads_parameters():
    """api_doc finds a parameter listed with others ("a, b : float") and refuses a missing one."""
    assert api_doc(("fit/views.py", "ViewsFitOptions"), "textured_iters")
    with pytest.raises(LookupError, match="no_such_parameter"):
        api_doc(("fit/mesh.py", "fit_mesh"), "no_such_parameter")
    with pytest.raises(LookupError, match="nothing_here"):
        api_doc(("fit/mesh.py", "nothing_here"))


_PROBE = textwrap.dedent("""
    import sys
    from geofit.cli import main
    code = main(sys.argv[1:])
    heavy = sorted(m for m in ("numpy", "open3d", "scipy", "trimesh", "embreex", "distributed")
                   if m in sys.modules)
    print("EXIT", code, "HEAVY", ",".join(heavy) or "-")
""")


def _probe(*argv: str):
    res = subprocess.run([sys.executable, "-c", _PROBE, *argv], capture_output=True, text=True,
                         timeout=120)
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("EXIT"))
    _, code, _, heavy = line.split()
    return int(code), heavy, res.stderr


@pytest.mark.parametrize("argv, match", [
    (["fit-mesh", "{tmp}/missing.ply"], "TARGET: .*missing.ply not found"),
    (["fit-mesh", "{tmp}"], "TARGET: expected a file, got the folder"),
    (["render", "{tmp}/missing.obj"], "MESH: .*not found"),
    (["fit-views", "{tmp}/no-capture"], "CAPTURE: .*not found"),
    (["fit-volume", "{tmp}/no-capture"], "CAPTURE: .*not found"),
    (["fit-nerf", "{tmp}/no-capture"], "CAPTURE: .*not found"),
    (["fit-volume", "--out", "{tmp}/a-file"], "--out: .*a-file is a file"),
    (["fit-nerf", "--out", "{tmp}/a-file/below"], "--out: cannot create the folder"),
    (["batch", "fit-mesh", "{tmp}/missing.obj", "--out", "{tmp}/o"], "TARGETS: .*not found"),
    (["batch", "fit-mesh", "{tmp}", "--out", "{tmp}/a-file"], "--out: .*a-file is a file"),
])
def test_bad_path_answered_before_heavy_imports(argv, match, tmp_path):
    """A wrong input or output path is refused with a one-line message naming the argument,
    before numpy, Open3D, scipy, trimesh, Embree or Dask are imported (so at once)."""
    import re

    (tmp_path / "a-file").write_text("x")
    code, heavy, err = _probe(*[a.format(tmp=tmp_path) for a in argv])
    assert code == 1 and heavy == "-", (heavy, err)
    assert re.search(match, err) and len(err.strip().splitlines()) == 1, err


def test_unwritable_out_refused_before_the_fit(tmp_path):
    """A folder that cannot be written is refused before any work (root ignores permission
    bits, so as root a read-only file system stands in)."""
    import os

    if os.geteuid() == 0:
        ro = "/sys"  # sysfs: root may not create files in it
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
    code, heavy, err = _probe("fit-mesh", "--out", str(ro))
    assert code == 1 and heavy == "-" and "--out: the folder" in err and "not writable" in err


def test_plot_scene_with_plotly():
    """plot_scene draws geofit's meshes (vertex colours), clouds and cameras (wireframes) when
    plotly is installed; a wrong object is refused naming it."""
    pytest.importorskip("plotly")
    from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    from geofit.pytorch3d.vis.plotly_vis import plot_scene
    from geofit.structures import Mesh, PointCloud, TexturesVertex

    m = ico_sphere(1)
    mesh = Mesh(m.verts, m.faces, TexturesVertex(np.full((m.n_verts, 3), 0.5)))
    R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    fig = plot_scene({"a": {"mesh": mesh}, "b": {"cloud": PointCloud(m.verts, m.verts * 0 + 1),
                                                 "cams": FoVPerspectiveCameras(R=R, T=T)}},
                     ncols=2)
    assert [t.type for t in fig.data] == ["mesh3d", "scatter3d", "scatter3d"]
    assert fig.data[0].vertexcolor[0] == "rgb(128,128,128)"
    assert np.isnan(np.asarray(fig.data[2].x, float)).sum() == 2  # one wireframe per camera
    with pytest.raises(TypeError, match="'thing' is a .*expected Meshes"):
        plot_scene({"a": {"thing": object()}})
