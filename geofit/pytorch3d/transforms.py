"""``pytorch3d.transforms`` is not provided: rotations come from scipy, camera transforms from
geofit's cameras."""
from ._common import missing_names

__all__: list = []

_SO3 = ("scipy.spatial.transform.Rotation.from_rotvec(log_rot).as_matrix() is the same (N, 3, 3) "
        "matrix as so3_exp_map(log_rot); Rotation.from_matrix(R).as_rotvec() is so3_log_map")
_ROT = ("scipy.spatial.transform.Rotation converts between rotation matrices, quaternions "
        "(as_quat / from_quat, scalar-last), axis-angle and Euler angles")
__getattr__ = missing_names("geofit.pytorch3d.transforms", {
    "so3_exp_map": _SO3, "so3_exponential_map": _SO3, "so3_log_map": _SO3,
    "quaternion_to_matrix": _ROT, "matrix_to_quaternion": _ROT, "axis_angle_to_matrix": _ROT,
    "euler_angles_to_matrix": _ROT, "random_rotations": _ROT,
    "Transform3d": "geofit's cameras apply their world-to-view and projection transforms "
                   "(get_world_to_view_transform, transform_points) as 4x4 numpy matrices",
    "Rotate": _ROT, "Translate": "add the translation to the points (numpy)",
})
