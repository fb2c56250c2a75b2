"""The shared validators of geofit._validate: one integer check for every public entry point."""
import numpy as np
import pytest

from geofit._validate import check_int


def test_check_int_accepts_python_and_numpy_integers():
    """Integers >= low come back as Python ints; None passes only when allowed."""
    assert check_int(3, "n") == 3 and type(check_int(np.int32(3), "n")) is int
    assert check_int(0, "n", 0) == 0
    assert check_int(None, "n", allow_none=True) is None


@pytest.mark.parametrize("value", [0, -2, 2.5, True, np.bool_(True), "3", None, np.float64(2.0)])
def test_check_int_rejects_with_the_shared_message(value):
    """Below low, a bool, a float, a string or None: ValueError naming the argument and bound."""
    with pytest.raises(ValueError, match=r"^n_rays: expected an integer >= 1, got "):
        check_int(value, "n_rays")


def test_check_int_type_error_option():
    """error=TypeError changes the exception for non-integers only, not for a low value."""
    with pytest.raises(TypeError, match="K: expected an integer >= 2"):
        check_int(2.0, "K", 2, error=TypeError)
    with pytest.raises(ValueError, match="K: expected an integer >= 2, got 1"):
        check_int(1, "K", 2, error=TypeError)



@pytest.mark.parametrize("value,message", [("abc", "expected a number"), (None, "expected a number"),
                                           (np.inf, "expected a finite number"),
                                           (np.nan, "expected a finite number")])
def test_check_finite_rejects(value, message):
    """Not a number, or not finite: ValueError naming the argument."""
    from geofit._validate import check_finite

    with pytest.raises(ValueError, match=f"^t: {message}"):
        check_finite(value, "t")


def test_check_finite_users():
    """The edge loss's target length and Softplus's threshold use the shared check."""
    from geofit import ico_sphere
    from geofit._validate import check_finite
    from geofit.loss import mesh_edge_loss
    from geofit.nn import Softplus

    assert check_finite(np.float32(-2.5), "t") == -2.5
    with pytest.raises(ValueError, match="target_length: expected a finite number"):
        mesh_edge_loss(ico_sphere(0), target_length=np.inf)
    with pytest.raises(ValueError, match="threshold: expected a number"):
        Softplus(threshold="high")


def test_as_instance_defaults_passes_and_rejects():
    """None gives the class's default instance, an instance comes back as it is, anything else
    is a TypeError naming the argument, the expected type and the type found."""
    from geofit._validate import as_instance
    from geofit.render.soft import SoftRasterizationSettings

    assert as_instance(None, SoftRasterizationSettings, "s") == SoftRasterizationSettings()
    s = SoftRasterizationSettings(image_size=8)
    assert as_instance(s, SoftRasterizationSettings, "s") is s
    with pytest.raises(TypeError, match=r"^s: expected SoftRasterizationSettings, got <class "):
        as_instance({}, SoftRasterizationSettings, "s")
    with pytest.raises(TypeError, match=r"^s: expected a settings object, got <class 'int'>"):
        as_instance(3, SoftRasterizationSettings, "s", "a settings object")
