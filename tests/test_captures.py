"""Captures as they are: no lights, masks or not, their background, lens distortion, the
NeRF-synthetic split folder; meshes as they come (GLB parts, Open3D tensor meshes, (V, F))."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from PIL import Image

from geofit import ico_sphere
from geofit.datasets import render_views
from geofit.io import load_mesh, load_views, save_views
from geofit.render import MeshRasterizer, RasterizationSettings
from geofit.structures import Mesh, MultiViewDataset, TexturesVertex, as_mesh
from geofit.structures.views import UNKNOWN_SILHOUETTES


def _coloured_sphere() -> Mesh:
    """A vertex-coloured sphere of radius 0.8, colours a smooth function of position."""
    s = ico_sphere(2)
    V = s.verts * 0.8
    colors = 0.2 + 0.6 * (0.5 + 0.5 * np.stack([V[:, 0], V[:, 1], -V[:, 2]], axis=1) / 0.8)
    return Mesh(V, s.faces, TexturesVertex(colors))


def _lit_capture(tmp_path: Path, background=(0.0, 0.0, 0.0)) -> Path:
    """geofit's renderer, a point light baked into the pixels, written with save_views."""
    data = render_views(_coloured_sphere(), np.arange(12) * 30.0, np.tile([0.0, 25.0], 6),
                        image_size=48, background=background, silhouettes="coverage")
    assert data.lights is not None
    save_views(tmp_path, data)
    return tmp_path


def test_a_capture_has_no_lights_and_keeps_its_background(tmp_path):
    """A loaded capture carries no lights; its background comes from the capture's metadata,
    else from the uniform colour outside the alpha."""
    back = load_views(_lit_capture(tmp_path, (0.1, 0.2, 0.3)))
    assert back.lights is None
    assert_allclose(back.background, [0.1, 0.2, 0.3])
    f = tmp_path / "transforms.json"
    meta = json.loads(f.read_text())
    del meta["background"]
    f.write_text(json.dumps(meta))
    back = load_views(tmp_path)
    assert_allclose(back.background, [0.1, 0.2, 0.3], atol=0.5 / 255 + 1e-6)  # 8-bit PNG
    meta["background"] = [0.0, 2.0, 0.0]
    f.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"transforms\.json\.background: expected RGB values"):
        load_views(tmp_path)


def test_a_capture_without_lights_fits_unlit_colours_and_the_printed_psnr_is_right(tmp_path):
    """Lights baked into the pixels, geometry known: the colour solve fits what the camera saw
    (colours within [0, 1]) and the held-out PSNR the fit reports equals PSNR computed with numpy
    from the hard render's faces and barycentrics on the capture's (black) background."""
    from geofit.fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views

    train = load_views(_lit_capture(tmp_path)).split(4)
    assert train.lights is None and train.held_out is not None
    fit = fit_mesh_to_views(train, options=ViewsFitOptions(
        init=_coloured_sphere(), silhouette_method="none", textured_method="lstsq"),
        progress=False)
    assert fit.colors.min() >= 0.0 and fit.colors.max() <= 1.0
    printed = ViewsEvaluator(train.held_out)(fit.mesh, fit.colors)["psnr"]

    h = train.held_out
    frag = MeshRasterizer(h.cameras, RasterizationSettings(image_size=h.image_size))(fit.mesh)
    p2f, bary = frag.pix_to_face[..., 0], frag.bary_coords[..., 0, :]
    face = np.maximum(p2f, 0) % fit.mesh.n_faces  # packed over the views' copies of the mesh
    corner_colors = np.clip(fit.colors, 0, 1)[fit.mesh.faces[face]]
    pred = np.einsum("nhwk,nhwkc->nhwc", bary, corner_colors)
    pred[p2f < 0] = h.background
    mse = np.mean((pred - h.images) ** 2)
    assert_allclose(printed, 10.0 * np.log10(1.0 / mse), rtol=0, atol=1e-6)
    assert printed > 25.0  # unlit colours explain lit pixels well on a smooth sphere


def test_a_capture_without_masks_says_silhouettes_are_unknown(tmp_path):
    """No masks, no alpha: silhouettes None (not all ones); the mesh fit refuses with the steps
    to make masks; a mix of masked and unmasked views is refused."""
    from geofit.fit.views import fit_mesh_to_views

    data = render_views(_coloured_sphere(), [0.0, 90.0, 180.0], 0.0, image_size=16)
    data.silhouettes = None
    save_views(tmp_path, data, format="opencv")
    assert not (tmp_path / "masks").exists()
    back = load_views(tmp_path)
    assert back.silhouettes is None and "silhouettes unknown" in repr(back)
    assert back.image_size == (16, 16) and len(back[1:]) == 2
    with pytest.raises(ValueError, match="fit_mesh_to_views needs silhouettes .*To make masks"):
        fit_mesh_to_views(back, progress=False)
    assert "rembg" in UNKNOWN_SILHOUETTES
    meta = json.loads((tmp_path / "cameras.json").read_text())
    Image.fromarray(np.full((16, 16), 255, np.uint8)).save(tmp_path / "m.png")
    meta["views"][1]["mask"] = "m.png"
    (tmp_path / "cameras.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"views\[1\]: image .* has a mask or alpha channel, "
                                         "the first view's has none"):
        load_views(tmp_path)


def test_volume_fit_runs_without_silhouettes(tmp_path):
    """fit_volume takes a dataset with unknown silhouettes (every pixel is scene)."""
    from geofit.fit import VolumeFitOptions, fit_volume

    data = render_views(_coloured_sphere(), np.arange(4) * 90.0, 0.0, image_size=16)
    data = MultiViewDataset(images=data.images, silhouettes=None, cameras=data.cameras)
    out = fit_volume(data, options=VolumeFitOptions(volume_size=16, levels=(8, 16),
                                                    iterations=(2, 2)), progress=False)
    assert np.all(np.isfinite(out.volume.densities))


def test_dataset_needs_images_or_silhouettes():
    data = render_views(_coloured_sphere(), [0.0, 90.0], 0.0, image_size=8)
    with pytest.raises(ValueError, match="silhouettes, images: expected at least one"):
        MultiViewDataset(images=None, silhouettes=None, cameras=data.cameras)
    with pytest.raises(ValueError, match="background"):
        MultiViewDataset(images=data.images, silhouettes=None, cameras=data.cameras,
                         background=[0.0, 0.0, 3.0])


def test_split_holds_out_every_kth_view_or_an_index():
    data = render_views(_coloured_sphere(), np.arange(10) * 36.0, 0.0, image_size=8)
    train = data.split(4)
    assert len(train) == 7 and len(train.held_out) == 3 and train.held_out.held_out is None
    assert_allclose(train.held_out.azim, [0.0, 144.0, 288.0])
    assert train.lights is data.lights and train.background is data.background
    assert len(data.split([1, 2]).held_out) == 2
    for bad in (1, [], 0, [20]):
        with pytest.raises(ValueError, match="held_out"):
            data.split(bad)


# --------------------------------------------------------------------------------------------
# Lens distortion
# --------------------------------------------------------------------------------------------

_W, _H, _F, _CX, _CY = 64, 48, 40.0, 32.0, 24.0


def _blob_capture(tmp_path: Path, k: dict, X=(0.5, 0.3, -1.0), model: str = "OPENCV"):
    """A nerfstudio capture of one bright point X seen by a camera at the origin (OpenGL pose:
    looking down -z), drawn as a Gaussian blob where the lens distortion ``k`` puts it; returns
    the folder and the pinhole pixel of X (corner convention)."""
    x, y = X[0] / -X[2], -X[1] / -X[2]  # OpenCV normalised coordinates (y down)
    pin = np.array([_CX + _F * x, _CY + _F * y])
    r2 = x * x + y * y
    if model == "OPENCV_FISHEYE":  # equidistant: theta_d = theta (1 + k1 theta^2 + ...)
        th = np.arctan(np.sqrt(r2))
        thd = th * (1 + sum(k.get(f"k{i}", 0) * th ** (2 * i) for i in range(1, 5)))
        xd, yd = x * thd / np.sqrt(r2), y * thd / np.sqrt(r2)
    else:
        radial = 1 + k.get("k1", 0) * r2 + k.get("k2", 0) * r2 ** 2
        xd = x * radial + 2 * k.get("p1", 0) * x * y + k.get("p2", 0) * (r2 + 2 * x * x)
        yd = y * radial + k.get("p1", 0) * (r2 + 2 * y * y) + 2 * k.get("p2", 0) * x * y
    ud, vd = _CX + _F * xd, _CY + _F * yd
    u, v = np.meshgrid(np.arange(_W) + 0.5, np.arange(_H) + 0.5)
    img = np.exp(-((u - ud) ** 2 + (v - vd) ** 2) / (2 * 1.2 ** 2))
    Image.fromarray(np.round(img * 255).astype(np.uint8)).convert("RGB").save(tmp_path / "a.png")
    meta = {"camera_model": model, "fl_x": _F, "fl_y": _F, "cx": _CX, "cy": _CY, "w": _W,
            "h": _H, **k, "frames": [{"file_path": "a.png",
                                      "transform_matrix": np.eye(4).tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    return tmp_path, pin, np.array([ud, vd])


def _centroid(img: np.ndarray) -> np.ndarray:
    """The blob's centre: the weighted centroid of its core (above 0.6 of the peak, where the
    distortion's change of scale across the blob barely shifts it)."""
    g = img[..., 0]
    g = np.where(g > 0.6 * g.max(), g, 0.0)
    v, u = np.mgrid[:g.shape[0], :g.shape[1]] + 0.5
    return np.array([(g * u).sum(), (g * v).sum()]) / g.sum()


@pytest.mark.parametrize("k, model", [
    ({"k1": 0.5}, "OPENCV"),
    ({"k1": -0.3, "k2": 0.1, "p1": 0.01, "p2": -0.02}, "OPENCV"),
    ({"k1": -0.2, "k2": 0.02, "k4": 0.01}, "OPENCV_FISHEYE"),
])
def test_nerfstudio_distortion_is_undistorted(tmp_path, k, model):
    """A point drawn where nerfstudio's k1 (k2, p1, p2; fisheye k1..k4) puts it lands, after
    loading, at its pinhole projection through the loaded camera (same K kept)."""
    folder, pin, distorted = _blob_capture(tmp_path, k, model=model)
    assert np.linalg.norm(distorted - pin) > 1.5  # the distortion moves the point visibly
    data = load_views(folder)
    X = np.array([[0.5, 0.3, -1.0]])
    proj = data.cameras.transform_points_screen(X, (_H, _W))[0, 0, :2]
    assert_allclose(proj, pin, atol=1e-9)
    assert_allclose(_centroid(data.images[0]), pin, atol=0.03)


def test_nerfstudio_unsupported_distortion_is_refused(tmp_path):
    """k4 of a perspective camera (an r^8 term OpenCV lacks) and unknown models are refused."""
    folder, _, _ = _blob_capture(tmp_path, {"k1": 0.1, "k4": 0.01})
    with pytest.raises(ValueError, match=r"k4: the r\^8 radial term"):
        load_views(folder)
    meta = json.loads((folder / "transforms.json").read_text())
    meta.update(k4=0.0, camera_model="EQUIRECTANGULAR")
    (folder / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="camera_model: 'EQUIRECTANGULAR' is not supported"):
        load_views(folder)


def test_colmap_opencv_model_is_undistorted_like_nerfstudio(tmp_path):
    """The same camera as a COLMAP OPENCV model gives the same undistorted image."""
    folder, pin, _ = _blob_capture(tmp_path, {"k1": 0.5})
    ns = load_views(folder)
    col = tmp_path / "colmap"
    (col / "images").mkdir(parents=True)
    shutil.copy(folder / "a.png", col / "images" / "a.png")
    (col / "cameras.txt").write_text(f"1 OPENCV {_W} {_H} {_F} {_F} {_CX} {_CY} 0.5 0 0 0\n")
    # OpenGL identity pose = OpenCV rotation diag(1, -1, -1) = quaternion (0, 1, 0, 0)
    (col / "images.txt").write_text("1 0 1 0 0 0 0 0 1 a.png\n\n")
    data = load_views(col)
    assert_allclose(data.images, ns.images, atol=1e-12)
    assert_allclose(_centroid(data.images[0]), pin, atol=0.03)


# --------------------------------------------------------------------------------------------
# The NeRF-synthetic split folder
# --------------------------------------------------------------------------------------------


def test_nerf_synthetic_split_folder_loads(tmp_path):
    """transforms_train.json + transforms_test.json (no transforms.json): the training views
    with the test views as held_out."""
    data = render_views(_coloured_sphere(), np.arange(8) * 45.0, 0.0, image_size=16)
    root = tmp_path / "lego"
    for split, views in (("train", data[:5]), ("test", data[5:])):
        save_views(tmp_path / split, views)
        shutil.copytree(tmp_path / split / "images", root / split)
        meta = json.loads((tmp_path / split / "transforms.json").read_text())
        for fr in meta["frames"]:
            fr["file_path"] = "./" + fr["file_path"].replace("images/", f"{split}/")[:-4]
        (root / f"transforms_{split}.json").write_text(json.dumps(meta))
    back = load_views(root)
    assert back.name == "lego" and len(back) == 5 and len(back.held_out) == 3
    assert_allclose(back.held_out.images, data.images[5:], atol=0.5 / 255)
    assert_allclose(back.cameras.get_camera_center(), data.cameras.get_camera_center()[:5],
                    atol=1e-9)


# --------------------------------------------------------------------------------------------
# Meshes as they come
# --------------------------------------------------------------------------------------------


def test_glb_scene_keeps_its_parts_and_names(tmp_path):
    """load_mesh(merge=False) keeps each node (transform applied) under its name; merge=True
    gives one mesh with every face."""
    import trimesh

    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(), node_name="body", geom_name="body")
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.0, 0.0]
    scene.add_geometry(trimesh.creation.icosphere(1), node_name="lid", geom_name="lid",
                       transform=T)
    path = tmp_path / "two.glb"
    scene.export(path)
    parts = load_mesh(path, merge=False)
    assert sorted(parts) == ["body", "lid"]
    assert parts["body"].n_faces == 12 and parts["lid"].n_faces == 80
    assert_allclose(parts["lid"].verts.mean(axis=0), [3.0, 0.0, 0.0], atol=1e-6)
    merged = load_mesh(path)
    assert isinstance(merged, Mesh) and merged.n_faces == 92
    stl = tmp_path / "box.stl"
    trimesh.creation.box().export(stl)
    assert list(load_mesh(stl, merge=False)) == ["box"]
    with pytest.raises(TypeError, match="merge: expected True or False"):
        load_mesh(path, merge="no")


def test_as_mesh_takes_open3d_tensor_meshes_and_vf_pairs():
    import open3d as o3d

    s = ico_sphere(1)
    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.array(s.verts)),
                                       o3d.utility.Vector3iVector(s.faces.astype(np.int32)))
    tensor = o3d.t.geometry.TriangleMesh.from_legacy(legacy)
    for m in (as_mesh(tensor), as_mesh((s.verts, s.faces)), as_mesh([s.verts, s.faces])):
        assert_allclose(m.verts, s.verts, atol=1e-6)
        np.testing.assert_array_equal(m.faces, s.faces)
    with pytest.raises(ValueError, match=r"mesh\[1\]"):
        as_mesh((s.verts, s.faces + 1000))
    with pytest.raises(TypeError, match=r"\(V, F\) pair"):
        as_mesh("sphere")


def test_nerf_fit_runs_without_silhouettes():
    """fit_nerf takes a dataset (and held-out views) with unknown silhouettes."""
    from geofit.fit.nerf import NerfConfig, fit_nerf

    data = render_views(_coloured_sphere(), np.arange(4) * 90.0, 0.0, image_size=16)
    data = MultiViewDataset(images=data.images, silhouettes=None, cameras=data.cameras)
    cfg = NerfConfig.scene(n_harmonic_functions=2, n_hidden_neurons=12, n_hidden_color=8,
                           n_harmonic_functions_dir=1, n_pts_per_ray=16, n_rays_per_image=32,
                           batch_size=2, hull_resolution=16, n_iter=4, density_grid_warmup=2,
                           density_grid_every=2, n_threads=1)
    res = fit_nerf(data.split(2), options=cfg, progress=False)
    assert len(res.history.loss) > 0 and np.all(np.isfinite(res.history.loss))


def test_soft_silhouettes_and_background_round_trip_exactly(tmp_path):
    """Tutorial 4's soft silhouettes as alpha and a white background: save_views then
    load_views keeps the (already composited) pixels and the background as they were."""
    data = render_views(_coloured_sphere(), [0.0, 120.0, 240.0], 10.0, image_size=24,
                        background=(1.0, 1.0, 1.0), silhouettes="soft")
    assert np.any((data.silhouettes > 0.01) & (data.silhouettes < 0.99))
    save_views(tmp_path, data, bit_depth=16)
    back = load_views(tmp_path)
    assert_allclose(back.images, data.images, atol=0.5 / 65535 + 1e-9)
    assert_allclose(back.background, [1.0, 1.0, 1.0])


@pytest.mark.parametrize("change, match", [
    ({"camera_model": "OPENCV_FISHEYE", "p1": 0.1}, r"p1, p2: a fisheye camera has no tangential"),
    ({"is_fisheye": "yes"}, r"is_fisheye: expected true or false"),
    ({"k1": "big"}, r"\.k1: expected a finite number"),
])
def test_bad_distortion_fields_are_named(tmp_path, change, match):
    folder, _, _ = _blob_capture(tmp_path, {"k1": 0.1})
    meta = json.loads((folder / "transforms.json").read_text())
    meta.update(change)
    (folder / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=match):
        load_views(folder)


def test_mixed_fisheye_frames_and_bad_opencv_dist_are_refused(tmp_path):
    folder, _, _ = _blob_capture(tmp_path, {"k1": 0.1})
    meta = json.loads((folder / "transforms.json").read_text())
    meta["frames"].append({**meta["frames"][0], "is_fisheye": True})
    (folder / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="frames mix fisheye and perspective cameras"):
        load_views(folder)
    cv = tmp_path / "cv"
    cv.mkdir()
    shutil.copy(folder / "a.png", cv / "a.png")
    view = {"image": "a.png", "K": [[_F, 0, _CX], [0, _F, _CY], [0, 0, 1]],
            "R": np.eye(3).tolist(), "t": [0, 0, 1]}
    for dist, ok in (([0.1, 0, 0, 0], True), ([0.1, 0.2], False), ("k1", False)):
        (cv / "cameras.json").write_text(json.dumps({"views": [{**view, "dist": dist}]}))
        if ok:
            assert load_views(cv).images.shape == (1, _H, _W, 3)
        else:
            with pytest.raises(ValueError, match=r"views\[0\]\.dist: expected OpenCV's 4, 5 or 8"):
                load_views(cv)


@pytest.mark.parametrize("model_id, n_params, match", [
    (42, 0, r"cameras\.bin@8: MODEL: unknown COLMAP camera model id 42"),
    (7, 5, r"cameras\.bin@8: MODEL: camera model 'FOV' is not supported"),
])
def test_colmap_binary_unknown_or_unsupported_models_are_refused(tmp_path, model_id, n_params,
                                                                  match):
    import struct

    sparse = tmp_path / "sparse" / "0"
    sparse.mkdir(parents=True)
    (sparse / "cameras.bin").write_bytes(struct.pack("<QiiQQ", 1, 1, model_id, 8, 6)
                                         + struct.pack(f"<{n_params}d", *[1.0] * n_params))
    (sparse / "images.bin").write_bytes(struct.pack("<Q", 0))
    with pytest.raises(ValueError, match=match):
        load_views(tmp_path)
