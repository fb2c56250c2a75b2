"""Tests for geofit.structures.MultiViewDataset (the one multi-view dataset type of tutorials 4, 5
and 6), and its renderer."""
from __future__ import annotations

import numpy as np
import pytest

from geofit import FoVPerspectiveCameras, Mesh, TexturesVertex, ico_sphere, look_at_view_transform
from geofit.structures import MultiViewDataset
from geofit.datasets import render_views, tutorial_views


def _cameras(n=3):
    R, T = look_at_view_transform(2.7, 0.0, np.linspace(0.0, 240.0, n))
    return FoVPerspectiveCameras(R=R, T=T)


def _object(level=2):
    m = ico_sphere(level)
    V = m.verts * np.array([0.9, 0.6, 0.5])
    return Mesh(V, m.faces, TexturesVertex(np.clip(0.5 + 0.4 * V, 0, 1)))


def test_keyword_construction_is_the_loader_contract():
    """images, silhouettes, cameras and name as keywords; held_out set afterwards; len,
    image_size, indexing, subset and downsample keep the other fields."""
    rng = np.random.default_rng(0)
    ds = MultiViewDataset(images=rng.random((3, 8, 6, 3)), silhouettes=rng.random((3, 8, 6)),
                          cameras=_cameras(), name="capture")
    assert len(ds) == 3 and ds.image_size == (8, 6) and ds.lights is None and ds.held_out is None
    ds.held_out = MultiViewDataset(images=None, silhouettes=np.zeros((1, 8, 6)),
                                   cameras=_cameras(1))
    sub = ds[[0, 2]]
    assert isinstance(sub, MultiViewDataset) and len(sub) == 2 and sub.held_out is ds.held_out
    np.testing.assert_array_equal(sub.images, ds.images[[0, 2]])
    np.testing.assert_array_equal(ds[1].silhouettes, ds.silhouettes[1:2])
    assert len(ds.subset(slice(0, 2))) == 2
    half = ds.downsample(2)
    assert half.image_size == (4, 3) and half.name == "capture"
    np.testing.assert_allclose(half.silhouettes[0, 0, 0], ds.silhouettes[0, :2, :2].mean())
    assert ds.downsample(1) is ds
    with pytest.raises(TypeError):
        MultiViewDataset(None, np.zeros((3, 8, 6)), _cameras())   # keywords only


@pytest.mark.parametrize("kw,exc,match", [
    ({"cameras": None}, TypeError, "cameras"),
    ({"silhouettes": np.zeros((2, 8, 8))}, ValueError, "silhouettes"),
    ({"silhouettes": np.zeros((3, 1, 8))}, ValueError, "silhouettes"),
    ({"silhouettes": np.full((3, 8, 8), 2.0)}, ValueError, r"silhouettes: expected values in"),
    ({"silhouettes": np.full((3, 8, 8), np.nan)}, ValueError, "silhouettes"),
    ({"images": np.zeros((3, 8, 8, 2))}, ValueError, "images"),
    ({"images": np.full((3, 8, 8, 3), 255.0)}, ValueError, r"images: expected values in"),
    ({"name": 3}, TypeError, "name"),
    ({"azim": np.zeros(2)}, ValueError, "azim"),
    ({"dist": -1.0}, ValueError, "dist"),
    ({"held_out": "views"}, TypeError, "held_out"),
    ({"mesh": np.zeros((3, 3))}, TypeError, "mesh"),
])
def test_validation_names_the_argument(kw, exc, match):
    args = {"images": np.zeros((3, 8, 8, 3)), "silhouettes": np.zeros((3, 8, 8)),
            "cameras": _cameras()}
    args.update(kw)
    with pytest.raises(exc, match=match):
        MultiViewDataset(**args)


def test_render_views_silhouette_kinds():
    """Soft silhouettes lie in [0, 1] with a soft rim; thresholded ones are their support as
    0/1; coverage masks are 0/1 and inside the thresholded ones."""
    obj = _object()
    kw = {"image_size": 24}
    soft = render_views(obj, [0.0, 90.0], 10.0, silhouettes="soft", **kw)
    thr = render_views(obj, [0.0, 90.0], 10.0, silhouettes="threshold", **kw)
    cov = render_views(obj, [0.0, 90.0], 10.0, silhouettes="coverage", **kw)
    np.testing.assert_array_equal(thr.silhouettes, (soft.silhouettes > 1e-4).astype(float))
    assert np.any((soft.silhouettes > 0.01) & (soft.silhouettes < 0.99))
    assert set(np.unique(cov.silhouettes)) <= {0.0, 1.0}
    assert np.all(cov.silhouettes <= thr.silhouettes)
    np.testing.assert_array_equal(soft.images, cov.images)
    assert soft.mesh is obj and soft.lights is not None and soft.elev.tolist() == [10.0, 10.0]
    with pytest.raises(ValueError, match="silhouettes"):
        render_views(obj, 0.0, 0.0, silhouettes="hard")
    with pytest.raises(ValueError, match="azim, elev"):
        render_views(obj, [0.0, 1.0, 2.0], [0.0, 1.0])


def test_tutorial_views_layouts():
    """Tutorial 4: elev linspace(0, 360), white background, soft silhouettes, Fibonacci
    held-out views with coverage masks; tutorials 5 and 6: generate_cow_renders' views with
    held-out views between the training azimuths at elevations 0 and 20."""
    t4 = tutorial_views(4, mesh=_object(), num_views=5, image_size=16, num_held_out=3)
    np.testing.assert_allclose(t4.elev, np.linspace(0, 360, 5))
    np.testing.assert_allclose(t4.azim, np.linspace(-180, 180, 5))
    np.testing.assert_allclose(t4.images[t4.silhouettes < 1e-6], 1.0)
    assert len(t4.held_out) == 3 and set(np.unique(t4.held_out.silhouettes)) <= {0.0, 1.0}
    t5 = tutorial_views(5, mesh=_object(), num_views=4, image_size=16, num_held_out=2)
    np.testing.assert_allclose(t5.azim, [0.0, 120.0, 240.0, 360.0])
    assert t5.images[t5.silhouettes == 0].max() == 0.0
    np.testing.assert_allclose(t5.held_out.elev, [0.0, 20.0])
    assert t5.name == "mesh" and t5.held_out.name == "mesh"
    with pytest.raises(ValueError, match="tutorial"):
        tutorial_views(3)
    with pytest.raises(ValueError, match="num_held_out"):
        tutorial_views(5, mesh=_object(), num_views=4, image_size=8, num_held_out=3)
    with pytest.raises(ValueError, match="num_held_out"):
        tutorial_views(5, mesh=_object(), num_views=4, image_size=8, num_held_out=-1)


def test_generate_cow_renders_returns_cameras_images_silhouettes():
    """The tutorials' helper unpacks as ``cameras, images, silhouettes`` with the views of
    tutorial_views(5); data_dir and mesh together are refused."""
    from geofit.datasets import generate_cow_renders

    obj = _object()
    cameras, images, silhouettes = generate_cow_renders(num_views=3, image_size=8, mesh=obj,
                                                        azimuth_range=90)
    t5 = tutorial_views(5, mesh=obj, num_views=3, image_size=8, num_held_out=0,
                        azimuth_range=90)
    assert len(cameras) == 3 and images.shape == (3, 8, 8, 3) and silhouettes.shape == (3, 8, 8)
    np.testing.assert_array_equal(images, t5.images)
    np.testing.assert_array_equal(cameras.R, t5.cameras.R)
    assert set(np.unique(silhouettes)) <= {0.0, 1.0}
    with pytest.raises(ValueError, match="data_dir"):
        generate_cow_renders(num_views=2, data_dir="x", mesh=obj)


def test_the_0_1_dataset_names_are_gone():
    """0.2.0 removed the deprecated spellings (CHANGELOG.md): MultiViewDataset.mesh_name and
    render_views(mesh_name=...)."""
    import geofit.datasets as ds

    t5 = tutorial_views(5, mesh=_object(), num_views=2, image_size=8, num_held_out=0)
    assert not hasattr(t5, "mesh_name")
    with pytest.raises(TypeError, match="mesh_name"):
        ds.render_views(_object(), [0.0], [0.0], image_size=8, mesh_name="x")


def test_every_multi_view_fit_shows_a_progress_bar_unless_asked_not_to(capsys):
    """fit_mesh_to_views, fit_volume and fit_nerf draw a tqdm bar on stderr by default and
    nothing with progress=False."""
    from geofit.fit import (
        ViewsFitOptions,
        VolumeFitOptions,
        fit_mesh_to_views,
        fit_nerf,
        fit_volume,
    )
    from geofit.fit.nerf import NerfConfig

    t4 = tutorial_views(4, mesh=_object(), num_views=3, image_size=16, num_held_out=0)
    t5 = tutorial_views(5, mesh=_object(), num_views=4, image_size=16, num_held_out=0)
    cfg = NerfConfig.scene(n_iter=3, n_hidden_neurons=8, n_rays_per_image=16, n_pts_per_ray=16,
                           hull_resolution=16, n_threads=1)
    runs = {"fit_mesh_to_views": lambda p: fit_mesh_to_views(t4,
            options=ViewsFitOptions(init=ico_sphere(1), silhouette_iters=2,
            textured_method="none"), progress=p),
            "fit_volume": lambda p: fit_volume(t5, options=VolumeFitOptions(volume_size=8,
                    n_pts_per_ray=16, iterations=2), progress=p),
            "fit_nerf": lambda p: fit_nerf(t5, options=cfg, progress=p)}
    for name, run in runs.items():  # fits
        capsys.readouterr()
        run(True)
        assert name in capsys.readouterr().err
        run(False)
        assert capsys.readouterr().err == ""
