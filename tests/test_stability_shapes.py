"""The test shapes of the volume and NeRF stability tables (geofit.tutorials.stability)."""
import numpy as np
import pytest

from geofit.shapes import TEST_SHAPES
from geofit.structures import TexturesVertex
from geofit.tutorials.stability import STABILITY_SHAPES, shape_views, stability_shape


@pytest.mark.parametrize("name", ["torus", "open_cylinder"])
def test_procedural_shape_is_normalised_and_coloured(name):
    """Largest absolute coordinate 1 around the vertex mean; one colour per vertex in
    [0.15, 0.85] that is an affine function of the position."""
    m = stability_shape(name)
    np.testing.assert_allclose(np.abs(m.verts - m.verts.mean(0)).max(), 1.0, rtol=1e-12)
    np.testing.assert_allclose(m.verts.mean(0), 0.0, atol=1e-12)
    assert isinstance(m.textures, TexturesVertex)
    c = m.textures.verts_features
    assert c.shape == m.verts.shape and c.min() >= 0.15 - 1e-12 and c.max() <= 0.85 + 1e-12
    np.testing.assert_allclose(c, 0.15 + 0.35 * (m.verts + 1.0), rtol=1e-12)
    assert m.n_faces == TEST_SHAPES[name]().n_faces


def test_torus_is_tilted_so_views_at_elevation_0_see_through_it():
    """The torus is turned 60 degrees about x: its y extent is no longer the flat torus' tube
    diameter (0.7 / 1.35 = 0.52 after normalising) but most of its ring (1.5 or more)."""
    m = stability_shape("torus")
    assert np.ptp(m.verts[:, 1]) > 1.5


def test_file_shape_from_the_data_folder(tmp_path, monkeypatch):
    """A name that is no procedural shape is read from $GEOFIT_DATA/shapes/<name>.obj."""
    (tmp_path / "shapes").mkdir()
    (tmp_path / "shapes" / "tet.obj").write_text(
        "v 0 0 0\nv 2 0 0\nv 0 2 0\nv 0 0 2\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path))
    m = stability_shape("tet")
    assert m.n_verts == 4 and m.n_faces == 4
    np.testing.assert_allclose(np.abs(m.verts).max(), 1.0, rtol=1e-12)


@pytest.mark.parametrize("bad", ["no_such_shape_xyz", "../etc/passwd", "", 3, None])
def test_unknown_shape_raises_naming_the_argument(bad, tmp_path, monkeypatch):
    """Unknown names, paths and non-strings: ValueError naming ``name``."""
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path))
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")
    with pytest.raises(ValueError, match="name"):
        stability_shape(bad)


def test_shape_views_are_tutorial_5_style_renders():
    """Black background, thresholded silhouettes covering the rendered pixels, held-out views."""
    d = shape_views("open_cylinder", num_views=4, image_size=24, num_held_out=2)
    assert d.images.shape == (4, 24, 24, 3) and d.name == "open_cylinder"
    assert set(np.unique(d.silhouettes)) <= {0.0, 1.0} and d.silhouettes.mean() > 0.05
    assert np.all(d.images[d.silhouettes == 0] == 0.0)
    assert len(d.held_out) == 2 and np.all(np.isfinite(d.images))


def test_default_stability_shapes_include_genus_1_and_open():
    assert {"torus", "open_cylinder"} <= set(STABILITY_SHAPES)
