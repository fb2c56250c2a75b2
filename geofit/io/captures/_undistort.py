"""Lens distortion removed with OpenCV: images and masks resampled to the pinhole camera with the
same ``K`` (private to geofit.io).

OpenCV's pixel centres sit at integer coordinates while geofit's (COLMAP's, nerfstudio's) sit at
``i + 0.5``: the principal point is shifted by half a pixel on the way in, and the remap of each
output pixel centre samples the distorted image at the matching OpenCV coordinate.
"""
from __future__ import annotations

import cv2  # opencv-python-headless: a well-kept exact inverse of OpenCV's lens models
import numpy as np

#: OpenCV's distortion coefficients, in the order cv2 takes them.
OPENCV_COEFFS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
#: OpenCV's fisheye (equidistant) coefficients.
FISHEYE_COEFFS = ("k1", "k2", "k3", "k4")


def undistort(images: np.ndarray, silhouettes: np.ndarray | None, K: np.ndarray,
              coeffs: np.ndarray, fisheye: bool):
    """Resample distorted views to pinhole views with the same intrinsics.

    Parameters
    ----------
    images : (N, H, W, 3) float64
        The distorted images.
    silhouettes : (N, H, W) float64 or None
        Their masks (resampled the same way).
    K : (N, 3, 3) float64
        Pixel intrinsics, (0, 0) at the corner of the top-left pixel; kept for the result.
    coeffs : (N, 8) or (N, 4) float64
        OpenCV's ``(k1, k2, p1, p2, k3, k4, k5, k6)`` or, with ``fisheye``, ``(k1, k2, k3,
        k4)``.
    fisheye : bool
        Use OpenCV's fisheye model.

    Returns
    -------
    images : (N, H, W, 3) float64
    silhouettes : (N, H, W) float64 or None
        Bilinear resampling; pixels whose source falls outside the image repeat the border.
    """
    N, H, W = images.shape[:3]
    shift = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    out_img = np.empty_like(images)
    out_sil = None if silhouettes is None else np.empty_like(silhouettes)
    maps: dict = {}
    for i in range(N):  # one remap per view (shared maps reused)
        Kcv = shift @ K[i]
        key = (Kcv.tobytes(), coeffs[i].tobytes())
        if key not in maps:
            if fisheye:
                maps[key] = cv2.fisheye.initUndistortRectifyMap(
                    Kcv, coeffs[i], np.eye(3), Kcv, (W, H), cv2.CV_32FC1)
            else:
                maps[key] = cv2.initUndistortRectifyMap(Kcv, coeffs[i], None, Kcv, (W, H),
                                                        cv2.CV_32FC1)
        mx, my = maps[key]
        out_img[i] = cv2.remap(images[i], mx, my, cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)
        if out_sil is not None:
            out_sil[i] = cv2.remap(silhouettes[i], mx, my, cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REPLICATE)
    np.clip(out_img, 0.0, 1.0, out=out_img)
    if out_sil is not None:
        np.clip(out_sil, 0.0, 1.0, out=out_sil)
    return out_img, out_sil
