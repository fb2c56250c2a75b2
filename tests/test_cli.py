"""The command line: sub-command discovery, the demo's output and its analytic silhouette."""
import numpy as np
import pytest
from PIL import Image

from geofit import ico_sphere
from geofit.cli import build_parser, main
from geofit.cli.demo import render_views


def test_parser_lists_demo():
    """Every registered sub-command shows up in the parser."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert "demo" in sub.choices


def test_no_command_prints_help_and_returns_2(capsys):
    assert main([]) == 2
    assert "usage: geofit" in capsys.readouterr().out


def test_demo_fits_the_shipped_cow(tmp_path, monkeypatch, capsys):
    """`geofit demo` (reduced size) fits the cow shipped with geofit, offline and without
    GEOFIT_DATA, and writes the picture, the fitted mesh as OBJ with its UV texture and as PLY
    with its vertex colours."""
    from geofit.cli.demo import run_demo
    from geofit.io import load_mesh

    monkeypatch.delenv("GEOFIT_DATA", raising=False)
    monkeypatch.delenv("GEOFIT_SHIPPED_DATA", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    res = run_demo(tmp_path / "out", views=4, size=32, heldout=2, time_budget=10.0)
    assert res.name == "cow"
    assert set(res.metrics) >= {"iou", "psnr", "chamfer_l2", "fscore@0.01"}
    assert 0.5 < res.metrics["iou"] <= 1.0 and np.isfinite(res.metrics["chamfer_l2"])
    img = np.asarray(Image.open(tmp_path / "out" / "demo.png"))
    assert img.shape[0] > 3 * 160 and img.shape[1] >= 2 * 160  # caption + targets, 2 fits
    assert (img < 250).any() and (img == 255).any()
    back = load_mesh(tmp_path / "out" / "fit.ply")
    np.testing.assert_array_equal(back.verts, res.mesh.verts)  # PLY keeps float64
    np.testing.assert_array_equal(back.faces, res.mesh.faces)
    assert back.textures.verts_features.shape == (res.mesh.n_verts, 3)
    obj = load_mesh(res.textured_file)  # the UV texture: fit.obj + fit.mtl + its PNG
    assert res.textured_file.name == "fit.obj"
    if hasattr(res.mesh.textures, "maps"):  # (a budget spent before it keeps vertex colours)
        assert (tmp_path / "out" / "fit.mtl").is_file()
        np.testing.assert_allclose(obj.textures.maps, res.mesh.textures.maps,
                                   atol=0.5 / 255 + 1e-9)
    else:
        np.testing.assert_allclose(obj.verts[obj.faces], res.mesh.verts[res.mesh.faces],
                                   atol=1e-6)
    assert np.isfinite(res.metrics["psnr_vertex"])
    text = capsys.readouterr().out
    assert "cow" in text and "held-out views: silhouette IoU" in text and "fit.ply" in text


def test_demo_command_line(tmp_path, monkeypatch):
    """`geofit demo --views ... --out ...` runs the same job from the command line."""
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")  # the procedural stand-in: smaller, faster
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "nothing-here"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert main(["demo", "--out", str(tmp_path), "--views", "3", "--size", "16", "--heldout", "1",
                 "--time-budget", "1"]) == 0
    assert (tmp_path / "demo.png").is_file() and (tmp_path / "fit.ply").is_file()


@pytest.mark.parametrize("kw, match", [({"views": 1}, "views"), ({"size": 8}, "size"),
                                       ({"size": 33}, "even"), ({"heldout": 0}, "heldout"),
                                       ({"time_budget": 0}, "time_budget")])
def test_run_demo_validation(tmp_path, kw, match):
    from geofit.cli.demo import run_demo

    with pytest.raises(ValueError, match=match):
        run_demo(tmp_path, **kw)
    assert not any(tmp_path.iterdir())  # nothing written before the check


def test_demo_sphere_silhouette_matches_analytic_disc():
    """A unit sphere at distance 2.7 under a 60 degree FoV covers a disc of NDC radius
    tan(asin(1/2.7)) / tan(30 deg); the rendered coverage matches its area to 1%."""
    res = render_views(ico_sphere(5), n_views=2, image_size=200)
    r = np.tan(np.arcsin(1 / 2.7)) / np.tan(np.radians(30))
    expected = np.pi * r**2 / 4.0
    np.testing.assert_allclose((res.face_ids >= 0).mean(axis=(1, 2)), expected, rtol=0.01)
    assert np.all(np.isfinite(res.images)) and res.images.min() >= 0 and res.images.max() <= 1


@pytest.mark.parametrize("kw, match", [({"n_views": 0}, "n_views"), ({"image_size": 4}, "image_size")])
def test_demo_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        render_views(ico_sphere(1), **kw)
