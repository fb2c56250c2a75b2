"""Assigning an attribute of lights, materials and cameras is validated as the constructor
validates its argument (shape, finiteness, range, batch size), for every light class and camera
class, and a failed assignment leaves the object unchanged (see also
tests/test_hardening_fixes.py for the issue's cases)."""
import numpy as np
import pytest

from geofit.cameras import (
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    PerspectiveCameras,
    look_at_view_transform,
)
from geofit.render import AmbientLights, DirectionalLights, Materials, PointLights


@pytest.mark.parametrize("make,name", [(PointLights, "location"), (PointLights, "ambient_color"),
                                       (DirectionalLights, "direction"),
                                       (DirectionalLights, "specular_color"),
                                       (AmbientLights, "ambient_color")])
@pytest.mark.parametrize("value,match", [("x", "expected real numbers"),
                                         ([[np.nan, 0, 0]], "expected finite"),
                                         ([[0.0, 1.0]], r"expected shape \(n, 3\)"),
                                         (np.zeros((0, 3)), r"expected shape \(n, 3\)")])
def test_light_assignment_is_validated(make, name, value, match):
    lights = make()
    before = getattr(lights, name).copy()
    with pytest.raises(ValueError, match=f"{name}: {match}"):
        setattr(lights, name, value)
    np.testing.assert_array_equal(getattr(lights, name), before)   # unchanged on failure


@pytest.mark.parametrize("name,value,match", [
    ("shininess", -1.0, "shininess: expected values >= 0"),
    ("shininess", [[1.0]], "shininess: expected a number or shape"),
    ("shininess", np.inf, "shininess: expected finite"),
    ("diffuse_color", [1.0, 1.0], r"diffuse_color: expected shape \(n, 3\)"),
    ("specular_color", "red", "specular_color: expected real numbers"),
    ("ambient_color", np.ones((2, 3)), None),
])
def test_material_assignment_is_validated(name, value, match):
    m = Materials()
    if match is None:      # a valid assignment broadcasts the batch
        setattr(m, name, value)
        assert len(m) == 2 and m.shininess.shape == (2,)
        return
    with pytest.raises(ValueError, match=match):
        setattr(m, name, value)


def _fov():
    R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    return FoVPerspectiveCameras(R=R, T=T)


@pytest.mark.parametrize("make,name,value,exc,match", [
    (_fov, "fov", 200.0, ValueError, r"fov: expected values in \(0, 180\)"),
    (_fov, "znear", -1.0, ValueError, "znear: expected > 0"),
    (_fov, "R", np.ones((3, 3)), ValueError, "R: expected rotation matrices"),
    (_fov, "T", [[1.0, 2.0]], ValueError, r"T: expected shape \(n, 3\)"),
    (_fov, "T", [[np.nan, 0.0, 0.0]], ValueError, "T: expected finite"),
    (_fov, "fov", [10.0, 20.0, 30.0], ValueError, "mismatched batch sizes"),
    (_fov, "degrees", "yes", TypeError, "degrees: expected True or False"),
    (_fov, "degrees", False, ValueError, r"fov: expected values in \(0, 3.14159\) radians"),
    (PerspectiveCameras, "focal_length", -2.0, ValueError, "focal_length"),
    (FoVOrthographicCameras, "max_x", -5.0, ValueError, "max_x"),
])
def test_camera_assignment_is_validated(make, name, value, exc, match):
    cams = make()
    before = {k: np.copy(v) for k, v in vars(cams).items() if isinstance(v, np.ndarray)}
    with pytest.raises(exc, match=match):
        setattr(cams, name, value)
    for k, v in before.items():          # the batch is unchanged on failure
        np.testing.assert_array_equal(getattr(cams, k), v)


def test_camera_assignment_rebuilds_the_batch():
    """A valid assignment takes effect everywhere (projection, inverse rotation, indexing)."""
    cams = _fov()
    cams.T = [0.0, 0.0, 3.0]
    assert cams.T.shape == (2, 3) and not cams.T.flags.writeable
    cams.fov = 30.0
    ref = FoVPerspectiveCameras(fov=30.0, R=cams.R, T=[0.0, 0.0, 3.0])
    p = np.array([[0.1, 0.2, 0.3]])
    np.testing.assert_allclose(cams.transform_points(p), ref.transform_points(p), rtol=1e-12)
    np.testing.assert_allclose(cams.get_camera_center(), ref.get_camera_center(), rtol=1e-12)
    assert cams[1].fov.tolist() == [30.0]
    with pytest.raises(ValueError, match="read-only"):
        cams.R[0, 0, 0] = 2.0
