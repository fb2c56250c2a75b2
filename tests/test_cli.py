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


def test_demo_writes_png_grid(tmp_path, monkeypatch):
    """`geofit demo` writes a PNG grid of the requested views (procedural mesh offline)."""
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "nothing-here"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert main(["demo", "--out", str(tmp_path), "--views", "3", "--size", "32"]) == 0
    img = np.asarray(Image.open(tmp_path / "demo.png"))
    assert img.shape == (32, 96, 3)
    assert (img < 250).any() and (img == 255).any()  # some object, some background


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
