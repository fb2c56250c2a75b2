"""Capture folders in and out: NeRF transforms.json, COLMAP text models, OpenCV K/R/t."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from PIL import Image

import geofit.datasets
import geofit.io
import geofit.structures
from geofit.cameras import (
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    PerspectiveCameras,
    look_at_view_transform,
)
from geofit.io.views import VIEW_FORMATS, load_views, save_views

H, W = 12, 20  # non-square


class _Views:
    """A minimal dataset (what save_views needs)."""

    def __init__(self, images, silhouettes, cameras):
        self.images, self.silhouettes, self.cameras = images, silhouettes, cameras


def _cow_renders(num_views: int, image_size: int):
    """The volume tutorial's training renders."""
    return geofit.datasets.tutorial_views(5, num_views=num_views, image_size=image_size,
                                          num_held_out=0)


def _dataset(off_centre: bool, n: int = 3, seed: int = 0) -> _Views:
    rng = np.random.default_rng(seed)
    R, T = look_at_view_transform(dist=3.0, elev=[10.0, -20.0, 35.0][:n],
                                  azim=[20.0, 150.0, 260.0][:n])
    if off_centre:
        cams = PerspectiveCameras(focal_length=[[1.7, 1.9]], principal_point=[[0.15, -0.1]],
                                  R=R, T=T)
    else:
        cams = FoVPerspectiveCameras(fov=40.0, R=R, T=T)
    images = rng.uniform(0, 1, size=(n, H, W, 3))
    sils = (rng.uniform(0, 1, size=(n, H, W)) > 0.5).astype(np.float64)
    return _Views(images, sils, cams)


_X = np.array([[0.1, 0.2, -0.3], [-0.4, 0.0, 0.25], [0.0, 0.0, 0.0]])


def _pixels(cams):
    return cams.transform_points_screen(_X, (H, W))[..., :2]


def _png(path: Path, a: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(a * 255).astype(np.uint8)).save(path)


@pytest.mark.parametrize("fmt", VIEW_FORMATS)
@pytest.mark.parametrize("off_centre", [False, True])
def test_round_trip_keeps_images_silhouettes_and_cameras(tmp_path, fmt, off_centre):
    """save_views then load_views: 8-bit images to half a level, silhouettes exactly, cameras
    reprojecting test points to 1e-6 px (non-square images, principal point on or off centre)."""
    data = _dataset(off_centre)
    written = save_views(tmp_path, data, format=fmt)
    assert written.is_file() and written.is_relative_to(tmp_path)
    back = load_views(tmp_path, znear=0.5)
    assert back.images.shape == (3, H, W, 3) and back.silhouettes.shape == (3, H, W)
    assert_allclose(back.images, data.images, atol=0.5 / 255 + 1e-12)
    np.testing.assert_array_equal(back.silhouettes, data.silhouettes)
    assert_allclose(_pixels(back.cameras), _pixels(data.cameras), atol=1e-6, rtol=0)
    assert_allclose(back.cameras.get_camera_center(), data.cameras.get_camera_center(),
                    atol=1e-9)
    assert isinstance(back.cameras, PerspectiveCameras if off_centre else FoVPerspectiveCameras)


@pytest.mark.parametrize("fmt", VIEW_FORMATS)
def test_sixteen_bit_pngs_keep_their_values(tmp_path, fmt):
    """bit_depth=16 writes 16-bit PNGs (colour through pypng, masks through pillow) and the
    loader keeps all 16 bits."""
    data = _dataset(False)
    data.silhouettes = np.random.default_rng(1).uniform(0, 1, size=(3, H, W))
    save_views(tmp_path, data, format=fmt, bit_depth=16)
    back = load_views(tmp_path)
    assert_allclose(back.images, data.images, atol=0.5 / 65535 + 1e-12)
    assert_allclose(back.silhouettes, data.silhouettes, atol=0.5 / 65535 + 1e-12)


def test_blender_transforms_camera_angle_x_and_paths_without_extension(tmp_path):
    """NeRF-synthetic style: camera_angle_x only, file_path "./train/r_0" without extension,
    RGBA images; a point one unit down the camera's -z axis lands on the image centre and the
    camera sits at the matrix's last column."""
    c2w = np.array([[1.0, 0.0, 0.0, 0.5], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 0.2],
                    [0.0, 0.0, 0.0, 1.0]])  # looks along +y, z up: Blender's usual set-up
    angle = 0.6911112070083618
    rgba = np.zeros((H, W, 4))
    rgba[3:9, 5:15] = [1.0, 0.5, 0.0, 1.0]
    _png(tmp_path / "train" / "r_0.png", rgba)
    (tmp_path / "transforms.json").write_text(json.dumps({
        "camera_angle_x": angle,
        "frames": [{"file_path": "./train/r_0", "rotation": 0.0,
                    "transform_matrix": c2w.tolist()}]}))
    data = load_views(tmp_path)
    assert_allclose(data.silhouettes[0], rgba[..., 3])
    assert_allclose(data.images[0], rgba[..., :3], atol=0.5 / 255)
    cams = data.cameras
    assert_allclose(cams.get_camera_center()[0], c2w[:3, 3], atol=1e-12)
    ahead = (c2w @ [0.0, 0.0, -1.0, 1.0])[:3]
    right = (c2w @ [0.1, 0.0, -1.0, 1.0])[:3]
    px = cams.transform_points_screen(np.stack([ahead, right]), (H, W))[0, :, :2]
    f = 0.5 * W / math.tan(0.5 * angle)
    assert_allclose(px, [[W / 2, H / 2], [W / 2 + 0.1 * f, H / 2]], atol=1e-9)
    white = load_views(tmp_path, background=(1.0, 1.0, 1.0))
    assert_allclose(white.images[0, 0, 0], [1.0, 1.0, 1.0])


def test_transforms_per_frame_intrinsics_override_the_top_level(tmp_path):
    """fl_x/fl_y/cx/cy per frame win over the top level; pixels follow K exactly."""
    for i in range(2):
        _png(tmp_path / f"im{i}.png", np.ones((H, W, 3)) * 0.5)
    eye = np.eye(4)
    eye[2, 3] = 3.0
    (tmp_path / "transforms.json").write_text(json.dumps({
        "fl_x": 30.0, "fl_y": 28.0, "cx": 9.0, "cy": 5.5, "w": W, "h": H,
        "frames": [{"file_path": "im0.png", "transform_matrix": eye.tolist()},
                   {"file_path": "im1.png", "transform_matrix": eye.tolist(), "fl_x": 40.0,
                    "cx": 11.0}]}))
    data = load_views(tmp_path)
    assert data.silhouettes is None  # RGB only: silhouettes unknown
    X = np.array([[0.2, -0.1, 1.0]])  # 2 units in front (the camera looks down -z)
    px = data.cameras.transform_points_screen(X, (H, W))[:, 0, :2]
    # OpenCV camera coordinates of X: x right = 0.2, y down = +0.1, depth 2
    assert_allclose(px, [[9.0 + 30.0 * 0.1, 5.5 + 28.0 * 0.05],
                         [11.0 + 40.0 * 0.1, 5.5 + 28.0 * 0.05]], atol=1e-9)


def _colmap(tmp_path: Path, model_line: str = "1 SIMPLE_PINHOLE 20 12 25.0 9.5 6.25",
            image_lines: str | None = None) -> Path:
    sparse = tmp_path / "sparse" / "0"
    sparse.mkdir(parents=True)
    (sparse / "cameras.txt").write_text(f"# Camera list\n{model_line}\n")
    if image_lines is None:
        c, s = math.cos(0.3), math.sin(0.3)
        image_lines = (f"# Image list\n1 {c} 0 {s} 0 0.1 -0.2 4.0 1 a.jpg\n\n"
                       f"2 1 0 0 0 0 0 5 1 sub/b.jpg\n1.0 2.0 -1 3.0 4.0 7\n")
    (sparse / "images.txt").write_text(image_lines)
    rgb = np.random.default_rng(2).uniform(0, 1, size=(H, W, 3))
    for name in ("a.jpg", "sub/b.jpg"):
        p = tmp_path / "images" / name
        p.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.round(rgb * 255).astype(np.uint8)).save(p, quality=95)
    mask = np.zeros((H, W))
    mask[2:8, 4:10] = 1.0
    _png(tmp_path / "masks" / "a.jpg.png", mask)     # COLMAP's NAME.png
    _png(tmp_path / "masks" / "sub" / "b.png", mask)  # STEM.png
    return tmp_path


def test_colmap_text_model_with_masks(tmp_path):
    """SIMPLE_PINHOLE, comment lines, an empty and a filled POINTS2D line, masks named NAME.png
    or STEM.png; pixels follow COLMAP's own projection to 1e-6 px."""
    data = load_views(_colmap(tmp_path))
    assert len(data.cameras) == 2 and data.images.shape == (2, H, W, 3)
    assert data.silhouettes[:, 2:8, 4:10].min() == 1.0 and data.silhouettes.sum() == 2 * 36
    c, s = math.cos(0.3), math.sin(0.3)
    # COLMAP's qvec2rotmat of (c, 0, s, 0): a rotation by 0.6 rad about y
    R = np.array([[1 - 2 * s * s, 0, 2 * c * s], [0, 1, 0], [-2 * c * s, 0, 1 - 2 * s * s]])
    x = _X @ R.T + [0.1, -0.2, 4.0]
    expect = x[:, :2] / x[:, 2:] * 25.0 + [9.5, 6.25]
    assert_allclose(_pixels(data.cameras)[0], expect, atol=1e-6, rtol=0)
    assert isinstance(data.cameras, PerspectiveCameras)  # cx 9.5 is off-centre (W/2 = 10)


def test_docstring_examples():
    """The Examples section of geofit.io.views runs as a doctest."""
    import doctest

    import geofit.io.views as mod

    result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 3 and result.failed == 0


def test_load_views_has_one_home_in_io():
    """load_views/save_views live in geofit.io only; the dataset type in geofit.structures."""
    assert load_views is geofit.io.load_views and save_views is geofit.io.save_views
    assert not hasattr(geofit.datasets, "load_views") and not hasattr(geofit.datasets, "save_views")
    assert geofit.MultiViewDataset is geofit.structures.MultiViewDataset
    assert not hasattr(geofit.datasets, "MultiViewDataset") or "MultiViewDataset" not in \
        geofit.datasets.__all__


# ---- bad input: ValueError naming the file and the field ---------------------------------


def _transforms(tmp_path: Path, frames: list, **top) -> Path:
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, **top,
                                                          "frames": frames}))
    return tmp_path


_EYE = np.eye(4).tolist()


def test_transforms_missing_image_names_file_and_frame(tmp_path):
    _png(tmp_path / "a.png", np.ones((H, W, 3)))
    _transforms(tmp_path, [{"file_path": "a", "transform_matrix": _EYE},
                           {"file_path": "missing/b", "transform_matrix": _EYE}])
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[1\]\.file_path: image "
                                         r".*missing/b.* not found"):
        load_views(tmp_path)


def test_transforms_matrix_that_is_not_a_rotation(tmp_path):
    _png(tmp_path / "a.png", np.ones((H, W, 3)))
    M = np.eye(4)
    M[:3, :3] *= 1.5
    _transforms(tmp_path, [{"file_path": "a.png", "transform_matrix": M.tolist()}])
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[0\]\.transform_matrix: "
                                         "not a rotation"):
        load_views(tmp_path)


@pytest.mark.parametrize("frames, top, match", [
    ([{"file_path": "a.png"}], {}, r"frames\[0\]\.transform_matrix: missing"),
    ([{"file_path": "a.png", "transform_matrix": [[1, 0], [0, 1]]}], {},
     r"frames\[0\]\.transform_matrix: expected shape 4x4"),
    ([{"file_path": "a.png", "transform_matrix": _EYE}], {"camera_angle_x": -1},
     r"frames\[0\]\.camera_angle_x: expected a positive number"),
    ([{"file_path": "a.png", "transform_matrix": _EYE}], {"camera_angle_x": None},
     r"frames\[0\]\.camera_angle_x: expected a positive number"),
    ([{"file_path": "a.png", "transform_matrix": _EYE, "w": 99}], {},
     r"frames\[0\]\.w: 99 does not match the image"),
    ([], {}, "frames: expected a non-empty list"),
    ([{"file_path": "../a.png", "transform_matrix": _EYE}], {},
     r"frames\[0\]\.file_path: path '\.\./a\.png' leaves the capture folder"),
])
def test_transforms_bad_fields(tmp_path, frames, top, match):
    _png(tmp_path / "cap" / "a.png", np.ones((H, W, 3)))
    _png(tmp_path / "a.png", np.ones((H, W, 3)))
    _transforms(tmp_path / "cap", frames, **top)
    with pytest.raises(ValueError, match=r"transforms\.json: " + match):
        load_views(tmp_path / "cap")


def test_paths_outside_the_capture_need_allow_outside(tmp_path):
    """An absolute path or ../ is refused by default and read with allow_outside=True."""
    _png(tmp_path / "outside.png", np.full((H, W, 3), 0.25))
    cap = tmp_path / "cap"
    cap.mkdir()
    for ref in (str(tmp_path / "outside.png"), "../outside.png"):
        _transforms(cap, [{"file_path": ref, "transform_matrix": _EYE}])
        with pytest.raises(ValueError, match=r"frames\[0\]\.file_path: (absolute path|path)"):
            load_views(cap)
        assert_allclose(load_views(cap, allow_outside=True).images, 64 / 255)


def test_images_of_different_sizes_are_refused(tmp_path):
    _png(tmp_path / "a.png", np.ones((H, W, 3)))
    _png(tmp_path / "b.png", np.ones((H + 1, W, 3)))
    _transforms(tmp_path, [{"file_path": n, "transform_matrix": _EYE} for n in ("a", "b")])
    with pytest.raises(ValueError, match=r"frames\[1\]: image .*b\.png.* is 13x20, the first "
                                         "view's 12x20"):
        load_views(tmp_path)


def test_unreadable_image_and_json(tmp_path):
    (tmp_path / "a.png").write_bytes(b"not an image")
    _transforms(tmp_path, [{"file_path": "a.png", "transform_matrix": _EYE}])
    with pytest.raises(ValueError, match=r"frames\[0\]: cannot read image .*a\.png"):
        load_views(tmp_path)
    (tmp_path / "transforms.json").write_text("{frames: oops")
    with pytest.raises(ValueError, match=r"transforms\.json: cannot read JSON"):
        load_views(tmp_path)


@pytest.mark.parametrize("model_line, image_lines, match", [
    ("1 FOV 20 12 25 25 10 6 0.1", None,
     r"cameras\.txt:2: MODEL: camera model 'FOV' is not supported"),
    ("1 PINHOLE 20 12 25 25 10", None, r"cameras\.txt:2: PARAMS: PINHOLE takes 4"),
    ("1 PINHOLE 20 12 25 x 10 6", None, r"cameras\.txt:2: fy: expected a number"),
    ("1 SIMPLE_PINHOLE 20 12 25 10 6", "1 1 0 0 0 0 0 5 1\n\n",
     r"images\.txt:1: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"),
    ("1 SIMPLE_PINHOLE 20 12 25 10 6", "1 one 0 0 0 0 0 5 1 a.jpg\n\n",
     r"images\.txt:1: QW: expected a number, got 'one'"),
    ("1 SIMPLE_PINHOLE 20 12 25 10 6", "1 2 0 0 0 0 0 5 1 a.jpg\n\n",
     r"images\.txt:1: QW QX QY QZ: expected a unit quaternion"),
    ("1 SIMPLE_PINHOLE 20 12 25 10 6", "1 1 0 0 0 0 0 5 7 a.jpg\n\n",
     r"images\.txt:1: CAMERA_ID: camera 7 is not in cameras\.txt"),
    ("1 SIMPLE_PINHOLE 20 12 25 10 6", "1 1 0 0 0 0 0 5 1 nope.jpg\n\n",
     r"images\.txt:1: NAME: image .*nope\.jpg.* not found"),
    ("1 SIMPLE_PINHOLE 20 12 25 10 6", "1 1 0 0 0 0 0 5 1 ../../x.jpg\n\n",
     r"images\.txt:1: NAME: path '\.\./\.\./x\.jpg' leaves"),
    ("1 SIMPLE_PINHOLE 30 12 25 10 6", None,
     r"images\.txt:2: image .*a\.jpg.* is 12x20 \(HxW\), the camera says 12x30"),
])
def test_colmap_bad_lines(tmp_path, model_line, image_lines, match):
    with pytest.raises(ValueError, match=match):
        load_views(_colmap(tmp_path, model_line, image_lines))


def test_colmap_missing_mask_is_named(tmp_path):
    _colmap(tmp_path)
    (tmp_path / "masks" / "sub" / "b.png").unlink()
    with pytest.raises(ValueError, match=r"images\.txt:4: NAME: no mask for 'sub/b\.jpg'"):
        load_views(tmp_path)


def test_opencv_rotation_and_matrix_fields(tmp_path):
    data = _dataset(True)
    save_views(tmp_path, data, format="opencv")
    cams = json.loads((tmp_path / "cameras.json").read_text())
    cams["views"][2]["R"] = (2 * np.eye(3)).tolist()
    (tmp_path / "cameras.json").write_text(json.dumps(cams))
    with pytest.raises(ValueError, match=r"cameras\.json: views\[2\]\.R: not a rotation"):
        load_views(tmp_path)
    cams["views"][2]["R"] = np.eye(3).tolist()
    cams["views"][1]["K"] = [[1, 0, 0], [0, 1, 0]]
    (tmp_path / "cameras.json").write_text(json.dumps(cams))
    with pytest.raises(ValueError, match=r"cameras\.json: views\[1\]\.K: expected shape 3x3"):
        load_views(tmp_path)


def test_load_and_save_argument_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="path: no such file or folder"):
        load_views(tmp_path / "nothing")
    with pytest.raises(ValueError, match="no capture found"):
        load_views(tmp_path)
    data = _dataset(False)
    with pytest.raises(ValueError, match="format: expected one of"):
        save_views(tmp_path, data, format="ply")
    with pytest.raises(ValueError, match="bit_depth: expected 8 or 16"):
        save_views(tmp_path, data, bit_depth=12)
    save_views(tmp_path, data)
    with pytest.raises(ValueError, match=r"transforms\.json' exists"):
        save_views(tmp_path, data)
    save_views(tmp_path, data, overwrite=True)
    ortho = _Views(data.images, data.silhouettes, FoVOrthographicCameras(R=data.cameras.R))
    with pytest.raises(TypeError, match="cameras: expected FoVPerspectiveCameras or"):
        save_views(tmp_path / "o", ortho)
    with pytest.raises(ValueError, match="dataset.silhouettes: expected shape"):
        save_views(tmp_path / "s", _Views(data.images, data.silhouettes[:, :-1], data.cameras))
    with pytest.raises(ValueError, match=r"background: expected RGB in \[0, 1\]"):
        load_views(tmp_path, background=(2.0, 0.0, 0.0))


# ---- acceptance: a fit on a written capture matches the fit on the renders -----------------


def _fit_volume(ds, **kw):
    """``fit_volume(dataset, options=VolumeFitOptions(**kw))`` without a progress bar."""
    from geofit.fit.volume import VolumeFitOptions, fit_volume

    return fit_volume(ds, options=VolumeFitOptions(**kw), progress=False)


def test_fit_volume_on_a_written_capture_matches_the_direct_fit(tmp_path):
    """geofit renders -> transforms.json (OpenGL camera-to-world, RGBA PNGs) -> load_views ->
    fit_volume: held-out PSNR within 0.5 dB of the same fit on the renders given directly."""
    from geofit.fit.volume import volume_metrics

    t0 = time.perf_counter()
    train = _cow_renders(8, 32)
    test = geofit.datasets.held_out_views(num_views=8, image_size=32, n_azimuths=3,
                                          elevations=(0.0,))
    save_views(tmp_path / "cap", train, format="transforms")
    assert (tmp_path / "cap" / "images" / "r_000.png").is_file()
    with Image.open(tmp_path / "cap" / "images" / "r_000.png") as im:
        assert im.mode == "RGBA"
    loaded = load_views(tmp_path / "cap")
    kw = dict(volume_size=16, levels=(16,), iterations=(25,), n_pts_per_ray=32)
    psnr = []
    for ds in (train, loaded):
        res = _fit_volume(ds, **kw)
        psnr.append(volume_metrics(res.volume, test.images, test.silhouettes, test.cameras,
                                   n_pts_per_ray=32).psnr)
    print("held-out PSNR direct, loaded:", psnr)
    assert psnr[0] > 14.0, psnr  # the fit learned something
    assert abs(psnr[1] - psnr[0]) < 0.5, psnr
    assert time.perf_counter() - t0 < 60.0


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


_BOTTOM = np.eye(4)
_BOTTOM[3, 0] = 0.5


@pytest.mark.parametrize("files, match", [
    ({"transforms.json": {"frames": [{"file_path": "a.png", "transform_matrix": _EYE}]}},
     r"frames\[0\]: no focal length \(expected fl_x or camera_angle_x\)"),
    ({"transforms.json": {"camera_angle_x": 3.5,
                          "frames": [{"file_path": "a.png", "transform_matrix": _EYE}]}},
     r"frames\[0\]\.camera_angle_x: expected radians in \(0, pi\)"),
    ({"transforms.json": {"camera_angle_x": 0.7,
                          "frames": [{"file_path": "a.png", "transform_matrix": _BOTTOM.tolist()}]}},
     r"frames\[0\]\.transform_matrix: expected a bottom row"),
    ({"transforms.json": {"camera_angle_x": 0.7, "frames": ["a.png"]}},
     r"frames\[0\]: expected an object, got str"),
    ({"transforms.json": {"camera_angle_x": 0.7,
                          "frames": [{"file_path": "", "transform_matrix": _EYE}]}},
     r"frames\[0\]\.file_path: expected a non-empty relative path"),
    ({"transforms.json": {"camera_angle_x": 0.7,
                          "frames": [{"file_path": "a.png", "mask_path": "m.png",
                                      "transform_matrix": _EYE}]}},
     r"frames\[0\]: mask .*m\.png.* is 3x3, its image 12x20"),
    ({"transforms.json": [1, 2]}, "expected a JSON object at the top level, got list"),
    ({"cameras.json": {"views": []}}, r"cameras\.json: views: expected a non-empty list"),
    ({"cameras.json": {"views": [{"image": "a.png", "K": np.eye(3).tolist(),
                                  "R": np.eye(3).tolist()}]}}, r"views\[0\]\.t: missing"),
    ({"cameras.json": {"views": [{"image": "a.png", "K": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]],
                                  "R": np.eye(3).tolist(), "t": [0, 0, 1]}]}},
     r"views\[0\]\.K: expected \[\[fx, 0, cx\]"),
    ({"cameras.txt": "# nothing\n", "images.txt": ""}, r"cameras\.txt: no cameras"),
    ({"cameras.txt": "1 PINHOLE 20 12 25 25 10 6\n", "images.txt": "# none\n"},
     r"images\.txt: no images"),
    ({"cameras.txt": "1 PINHOLE 20 12 25 25 10 6\n"}, r"images\.txt: missing"),
    ({"cameras.txt": "1 PINHOLE\n", "images.txt": ""}, r"cameras\.txt:1: expected CAMERA_ID"),
    ({"cameras.txt": "x PINHOLE 20 12 25 25 10 6\n", "images.txt": ""},
     r"cameras\.txt:1: CAMERA_ID: expected an integer"),
    ({"cameras.txt": "1 PINHOLE 20 12 -25 25 10 6\n", "images.txt": ""},
     r"cameras\.txt:1: expected positive focal lengths"),
])
def test_more_bad_captures(tmp_path, files, match):
    """Each malformed capture file gets a ValueError naming the file and the field or line."""
    _png(tmp_path / "a.png", np.ones((H, W, 3)))
    _png(tmp_path / "m.png", np.ones((3, 3)))
    for name, content in files.items():
        _write(tmp_path / name, content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(ValueError, match=match):
        load_views(tmp_path)


def test_a_file_that_is_no_capture(tmp_path):
    with pytest.raises(ValueError, match=r"a\.png: not a capture file"):
        _png(tmp_path / "a.png", np.ones((H, W, 3)))
        load_views(tmp_path / "a.png")


def _colmap_text_to_binary(model: Path) -> None:
    """Rewrite a COLMAP text model (PINHOLE cameras) as cameras.bin / images.bin (COLMAP's
    little-endian layout) and remove the text files."""
    import struct

    cams = [ln.split() for ln in (model / "cameras.txt").read_text().splitlines()
            if ln and not ln.startswith("#")]
    out = struct.pack("<Q", len(cams))
    for c in cams:
        out += struct.pack("<iiQQ", int(c[0]), 1, int(c[2]), int(c[3]))
        out += struct.pack("<4d", *map(float, c[4:8]))
    (model / "cameras.bin").write_bytes(out)
    ims = [ln.split() for ln in (model / "images.txt").read_text().splitlines()
           if ln and not ln.startswith("#")]
    out = struct.pack("<Q", len(ims))
    for f in ims:
        out += struct.pack("<I7dI", int(f[0]), *map(float, f[1:8]), int(f[8]))
        out += f[9].encode() + b"\0" + struct.pack("<Q", 1) + struct.pack("<ddq", 1.0, 2.0, -1)
    (model / "images.bin").write_bytes(out)
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        (model / name).unlink()


def test_colmap_binary_model_reads_as_the_text_one(tmp_path):
    """A COLMAP binary model (cameras.bin, images.bin) gives the same views and cameras."""
    data = _dataset(True)
    save_views(tmp_path, data, format="colmap")
    text = load_views(tmp_path, znear=0.5)
    _colmap_text_to_binary(tmp_path / "sparse/0")
    back = load_views(tmp_path, znear=0.5)
    np.testing.assert_array_equal(back.images, text.images)
    np.testing.assert_array_equal(back.silhouettes, text.silhouettes)
    assert_allclose(_pixels(back.cameras), _pixels(data.cameras), atol=1e-6, rtol=0)
    (tmp_path / "sparse/0/images.bin").write_bytes(b"\1\0\0\0\0\0\0\0\1\0")
    with pytest.raises(ValueError, match=r"images\.bin: truncated at byte 8"):
        load_views(tmp_path)


def test_capture_registry_merges_one_table_per_layout_module():
    """Every layout module ends in a _loaders table and a detect(); the registry is their union
    and save_views writes exactly the layouts with a _savers table."""
    from geofit.io import captures

    for m in captures._MODULES:
        assert m._loaders and callable(m.detect)
        assert set(m._loaders) <= set(captures.LOADERS)
    assert set(captures.LOADERS) == {"transforms", "nerf_synthetic", "nerfstudio", "colmap",
                                     "opencv"}
    assert VIEW_FORMATS == tuple(captures.SAVERS) == ("transforms", "colmap", "opencv")
