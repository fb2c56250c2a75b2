"""Small fixes of issue 18 outside the loaders: each test states the invariant it guards."""
from __future__ import annotations

import time

import numpy as np
import pytest

from geofit import Mesh, ico_sphere
from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
from geofit.structures import MultiViewDataset
from geofit.fit import MeshFitOptions, VolumeFitOptions, fit_mesh, fit_volume
from geofit.fit.nerf import NerfConfig, fit_nerf


def _cameras(n: int) -> FoVPerspectiveCameras:
    R, T = look_at_view_transform(2.7, 10.0, np.linspace(0, 90, n))
    return FoVPerspectiveCameras(R=R, T=T)


def test_fit_mesh_source_with_repeated_index_face():
    """A source face (a, a, b) cannot get an area by moving vertices: fit_mesh leaves it, does
    not die on a read-only array, and fits as well as without it."""
    s = ico_sphere(2)
    F = s.faces.copy()
    F[0] = [F[0, 0], F[0, 0], F[0, 1]]
    F[5] = [F[5, 0], F[5, 1], F[5, 1]]
    target = s.update_verts(s.verts * [1.5, 1.0, 0.8])
    res = fit_mesh(target, recipe="sphere",
                   options=MeshFitOptions(init=Mesh(s.verts, F), n_iter=15), seed=0,
                   progress=False)
    ref = fit_mesh(target, recipe="sphere", options=MeshFitOptions(init=s, n_iter=15), seed=0,
                   progress=False)
    assert "the source had 2 zero-area triangles" in res.message
    assert np.isfinite(res.mesh.verts).all()
    assert res.history.loss[-1] <= 1.1 * ref.history.loss[-1]


def test_fit_mesh_collapsed_face_repaired_over_rounds():
    """A face whose three vertices coincide (distinct indices) is repaired by moving them;
    several repair rounds run without the read-only error."""
    from geofit.fit._mesh_plan import repair_degenerate

    s = ico_sphere(2)
    V = s.verts.copy()
    f = s.faces[0]
    V[f] = V[f[0]]
    nb = s.faces[np.isin(s.faces, f).any(axis=1)]
    V[np.unique(nb)] = V[f[0]]  # collapse the face's whole neighbourhood: needs more rounds
    mesh, n_bad, n_moved = repair_degenerate(Mesh(V, s.faces), max_rounds=10)
    assert n_bad > 1 and n_moved >= 3
    assert (mesh.face_areas > 0).sum() > (Mesh(V, s.faces).face_areas > 0).sum()


@pytest.mark.parametrize("fit", ["volume", "nerf"])
def test_fits_refuse_8bit_images(fit):
    """uint8 images or 0-255 float images: ValueError naming images (they used to be clipped to
    white or fitted as they were)."""
    cams = _cameras(2)
    sils = np.zeros((2, 8, 8))
    def data(im):
        return MultiViewDataset(images=im, silhouettes=sils, cameras=cams)

    call = ((lambda im: fit_volume(data(im), options=VolumeFitOptions(volume_size=8),
            progress=False)) if fit == "volume"
            else (lambda im: fit_nerf(data(im), options=NerfConfig.scene(n_iter=1),
                                      progress=False)))
    with pytest.raises(ValueError, match=r"^images: expected float values in \[0, 1\], got "
                                         r"integer dtype uint8"):
        call(np.full((2, 8, 8, 3), 200, np.uint8))
    with pytest.raises(ValueError, match=r"^images: expected values in \[0, 1\], got range "
                                         r"\[0, 255\]"):
        call(np.linspace(0, 255, 2 * 8 * 8 * 3).reshape(2, 8, 8, 3))


def test_show_open3d_without_display_raises_at_once(monkeypatch):
    """With no DISPLAY / WAYLAND_DISPLAY the interactive viewer raises instead of waiting for a
    window no one can close."""
    pytest.importorskip("open3d")
    from geofit.render.open3d import show_open3d

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    t = time.perf_counter()
    with pytest.raises(RuntimeError, match="show_open3d: no display .* render_open3d"):
        show_open3d(ico_sphere(1), _cameras(1), (32, 32))
    assert time.perf_counter() - t < 5.0


def test_light_and_material_assignment_validated_like_the_constructor():
    """`lights.location = [[0, 0, 1]]` (a list) becomes a checked, broadcast, read-only array;
    wrong shapes, non-finite values, mismatched batch sizes and negative shininess raise."""
    from geofit.render import DirectionalLights, Materials, PointLights

    lights = PointLights(location=[[0.0, 0.0, -3.0]])
    lights.location = [[0, 0, 1]]
    assert isinstance(lights.location, np.ndarray) and not lights.location.flags.writeable
    np.testing.assert_array_equal(lights.location, [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(lights.diffuse(np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3))),
                               [[0.3, 0.3, 0.3]])
    with pytest.raises(ValueError, match=r"location: expected shape \(n, 3\) or \(3,\)"):
        lights.location = [[0, 0]]
    with pytest.raises(ValueError, match="location: expected finite values"):
        lights.location = [[np.nan, 0, 0]]
    lights.location = np.zeros((3, 3))  # a batch of 3: the others broadcast to it
    assert len(lights) == 3 and lights.ambient_color.shape == (3, 3)
    with pytest.raises(ValueError, match="mismatched batch sizes"):
        lights.diffuse_color = np.zeros((2, 3))
    d = DirectionalLights()
    with pytest.raises(ValueError, match="direction: expected real numbers"):
        d.direction = "up"
    m = Materials()
    m.shininess = 5
    np.testing.assert_array_equal(m.shininess, [5.0])
    with pytest.raises(ValueError, match="shininess: expected values >= 0"):
        m.shininess = -1
    with pytest.raises(ValueError, match=r"specular_color: expected shape"):
        m.specular_color = [1, 2]


def test_camera_assignment_validated_like_the_constructor():
    """`cameras.T = [0, 0, 3]` is checked and broadcast as in the constructor (read-only copy,
    inverse rotation refreshed); a non-rotation R, fov >= 180, znear < 0, a wrong shape and a
    mismatched batch size raise ValueError naming the argument."""
    from geofit.cameras import FoVOrthographicCameras, PerspectiveCameras

    cams = _cameras(2)
    cams.T = [0, 0, 3]
    np.testing.assert_array_equal(cams.T, [[0.0, 0.0, 3.0]] * 2)
    assert not cams.T.flags.writeable
    cams.R = cams.R[:1]  # one rotation for both cameras; the centres follow (-T R^T)
    assert cams.R.shape == (2, 3, 3)
    np.testing.assert_allclose(cams.get_camera_center(), -cams.T @ cams.R[0].T, atol=1e-12)
    for name, bad, match in (("R", np.ones((3, 3)), "R: expected rotation matrices"),
                             ("fov", 200.0, r"fov: expected values in \(0, 180\)"),
                             ("znear", -1.0, "znear: expected > 0"),
                             ("T", [[0.0, 0.0]], r"T: expected shape \(n, 3\)"),
                             ("T", np.zeros((3, 3)), "mismatched batch sizes")):
        with pytest.raises(ValueError, match=match):
            setattr(cams, name, bad)
    p = PerspectiveCameras()
    p.focal_length = 2.0
    np.testing.assert_array_equal(p.focal_length, [[2.0, 2.0]])
    o = FoVOrthographicCameras()
    with pytest.raises(ValueError, match="scale_xyz"):
        o.scale_xyz = [[1.0, 2.0]]
