"""PyTorch3D's ``pytorch3d.loss`` on the tape: the chamfer distance and the mesh regularisers.

Each function computes geofit's value and analytic gradient in one call
(:mod:`geofit.loss`) and returns a scalar :class:`~.tensor.Tensor` whose recorded vjp is
``g * grad``: ``loss.backward()`` then costs nothing beyond the forward pass.
"""
from __future__ import annotations

import numpy as np

from .. import loss as _gl
from ..loss import chamfer as _chamfer
from ._common import missing_names
from .structures import Meshes, Pointclouds
from .tensor import Tensor

__all__ = ["chamfer_distance", "mesh_edge_loss", "mesh_laplacian_smoothing",
           "mesh_normal_consistency"]


def _cloud(x, lengths, normals, name: str):
    """A Pointclouds or (N, P, 3) tensor -> (padded Tensor, lengths, normals Tensor or None)."""
    if isinstance(x, Pointclouds):
        if lengths is not None:
            raise ValueError(f"{name}_lengths: not allowed with a Pointclouds {name}")
        n = x.normals_padded() if normals is None else normals
        return x.points_padded(), x.num_points_per_cloud().data, n
    if not isinstance(x, Tensor):
        x = Tensor(np.asarray(x, np.float64))
    if normals is not None and not isinstance(normals, Tensor):
        normals = Tensor(np.asarray(normals, np.float64))
    return x, None if lengths is None else np.asarray(getattr(lengths, "data", lengths)), normals


def _chamfer_with_grads(**kw):
    """geofit's chamfer distance with its gradients: (loss, loss_n, gx, gy, gxn, gyn)."""
    r = _chamfer.chamfer_distance(**kw)
    return r.loss, r.loss_normals, r.grad_x, r.grad_y, r.grad_x_normals, r.grad_y_normals


def chamfer_distance(x, y, x_lengths=None, y_lengths=None, x_normals=None, y_normals=None,
                     weights=None, batch_reduction: str | None = "mean",
                     point_reduction: str = "mean", norm: int = 2,
                     single_directional: bool = False, abs_cosine: bool = True):
    """Chamfer distance between two batches of clouds, ``loss, loss_normals`` (PyTorch3D).

    Parameters
    ----------
    x, y : (N, P, 3) Tensors / arrays, or Pointclouds
        E.g. the samples of ``sample_points_from_meshes``.
    x_lengths, y_lengths : (N,) int, optional
    x_normals, y_normals : (N, P, 3), optional
    weights : (N,) float, optional
    batch_reduction : {"mean", "sum", None}
    point_reduction : {"mean", "sum", "max"}
    norm : {2, 1}
    single_directional, abs_cosine : bool
        All as :func:`geofit.loss.chamfer_distance` (PyTorch3D's semantics: squared distances,
        mean per direction, the two directions summed).

    Returns
    -------
    loss : Tensor
        A scalar (``(N,)`` with ``batch_reduction=None``), recorded on the tape with its
        gradients to ``x`` and ``y`` (and to the normals for the normal term).
    loss_normals : Tensor or None
        None without normals.
    """
    X, xl, XN = _cloud(x, x_lengths, x_normals, "x")
    Y, yl, YN = _cloud(y, y_lengths, y_normals, "y")
    w = None if weights is None else np.asarray(getattr(weights, "data", weights), np.float64)
    loss, loss_n, gx, gy, gxn, gyn = _chamfer_with_grads(
        x=X.data, y=Y.data, x_lengths=xl, y_lengths=yl,
        x_normals=None if XN is None else XN.data, y_normals=None if YN is None else YN.data,
        weights=w, batch_reduction=batch_reduction, point_reduction=point_reduction,
        norm=norm, single_directional=single_directional, abs_cosine=abs_cosine)

    def scaled(g, grad):
        # batch_reduction=None: member b's gradient (only in row b) times g[b]
        g = np.asarray(g)
        if g.ndim == 0:
            return g * grad
        return grad * g.reshape((-1,) + (1,) * (grad.ndim - 1))

    out = Tensor._record(np.asarray(loss, np.float64), (X, Y),
                         lambda g: (scaled(g, gx), scaled(g, gy)))
    out_n = None
    if loss_n is not None:
        out_n = Tensor._record(np.asarray(loss_n, np.float64), (XN, YN),
                               lambda g: (scaled(g, gxn), scaled(g, gyn)))
    return out, out_n


def _mesh_term(meshes, fn, *args) -> Tensor:
    if not isinstance(meshes, Meshes):
        raise TypeError(f"meshes: expected geofit.pytorch3d.structures.Meshes, got "
                        f"{type(meshes)!r}")
    if meshes.isempty():
        return Tensor(np.zeros(()))
    value, grad = fn(meshes._geofit_batch(), *args)
    return Tensor._record(np.asarray(value, np.float64), (meshes.verts_packed(),),
                          lambda g: (g * grad,))


def mesh_edge_loss(meshes: Meshes, target_length: float = 0.0) -> Tensor:
    """Mean squared deviation of the edge lengths from ``target_length``, averaged over the
    batch (:func:`geofit.loss.mesh_edge_loss`)."""
    return _mesh_term(meshes, _gl.mesh_edge_loss, target_length)


def mesh_normal_consistency(meshes: Meshes) -> Tensor:
    """Mean ``1 - cos`` between the normals of faces sharing an edge
    (:func:`geofit.loss.mesh_normal_consistency`)."""
    return _mesh_term(meshes, _gl.mesh_normal_consistency)


def mesh_laplacian_smoothing(meshes: Meshes, method: str = "uniform") -> Tensor:
    """Laplacian smoothing, ``"uniform"``, ``"cot"`` or ``"cotcurv"``
    (:func:`geofit.loss.mesh_laplacian_smoothing`; the Laplacian is a constant, as in
    PyTorch3D)."""
    return _mesh_term(meshes, _gl.mesh_laplacian_smoothing, method)


__getattr__ = missing_names("geofit.pytorch3d.loss", {
    "point_mesh_face_distance": "geofit.loss.PointToSurface(target_mesh).loss(points) gives the "
                                "exact squared point-to-surface distance and its gradient",
    "point_mesh_edge_distance": "geofit.raycast.PointToMeshDistance for distances to a surface",
})
