"""PyTorch3D's ``pytorch3d.ops``: ``sample_points_from_meshes`` on the tape.

The samples of a mesh are a linear function of its vertices once the faces and barycentrics are
drawn, ``points = B @ verts`` with geofit's sparse ``(n, V)`` sampling matrix ``B``
(:func:`geofit.ops.barycentric_matrix`), so the recorded vjp is ``dL/dV = B.T @ dL/dP``. The
random choice of faces carries no gradient (as PyTorch3D's ``multinomial``).
"""
from __future__ import annotations

import numpy as np

from ..ops import sampling as _sampling
from ._common import missing_names
from .structures import Meshes
from .tensor import Tensor, default_rng, stack
from .textures import TexturesVertex

__all__ = ["sample_points_from_meshes"]


# geofit's sampler that keeps the sparse Jacobian (``SampledPoints`` with ``B``)
_SAMPLER = getattr(_sampling, "sample_points_with_jacobian", None) or \
    _sampling.sample_points_from_meshes


def _draw(mesh, n: int, rng, normals: bool):
    """geofit's sampler for one mesh: SampledPoints (points, normals, face_idx, bary, B)."""
    return _SAMPLER(mesh, n, seed=rng, return_normals=normals)


def sample_points_from_meshes(meshes: Meshes, num_samples: int = 10000,
                              return_normals: bool = False, return_textures: bool = False,
                              *, seed=None):
    """Sample points uniformly (by area) on each mesh of a batch (PyTorch3D's signature).

    Parameters
    ----------
    meshes : Meshes
    num_samples : int
        Points per mesh.
    return_normals : bool
        Also return the unit normal of each sample's face (a constant: no gradient flows to the
        vertices through it).
    return_textures : bool
        Also return each sample's texture value (``TexturesVertex`` features are interpolated
        with the same sparse matrix and get a gradient; ``TexturesUV`` colours are constants).
    seed : int or numpy.random.Generator, optional
        Beyond PyTorch3D: a seed for this call; default: the generator of
        :func:`geofit.pytorch3d.tensor.manual_seed`.

    Returns
    -------
    samples : (N, num_samples, 3) Tensor
        Recorded on the tape when the vertices require a gradient.
    normals : (N, num_samples, 3) Tensor
        Only with ``return_normals``.
    textures : (N, num_samples, C) Tensor
        Only with ``return_textures``.
    """
    if not isinstance(meshes, Meshes):
        raise TypeError(f"meshes: expected geofit.pytorch3d.structures.Meshes, got "
                        f"{type(meshes)!r}")
    if meshes.isempty():
        raise ValueError("meshes: the batch is empty")
    rng = default_rng() if seed is None else np.random.default_rng(seed)
    if (not isinstance(num_samples, (int, np.integer)) or isinstance(num_samples, bool)
            or num_samples < 1):
        raise ValueError(f"num_samples: expected an integer >= 1, got {num_samples!r}")
    n = int(num_samples)
    draws = [_draw(m, n, rng, return_normals) for m in meshes._geofit()]  # batch members
    Bs = [d.B for d in draws]

    def vjp(g):  # (N, n, 3) -> packed (sum V, 3)
        return (np.concatenate([B.T @ g[i] for i, B in enumerate(Bs)]),)

    # one member: a view of its fresh points array (no copy)
    pts = draws[0].points[None] if len(draws) == 1 else np.stack([d.points for d in draws])
    points = Tensor._record(pts, (meshes.verts_packed(),), vjp)
    out = [points]
    if return_normals:
        out.append(Tensor(np.stack([d.normals for d in draws])))
    if return_textures:
        tex = meshes.textures
        if tex is None:
            raise ValueError("return_textures: the meshes have no textures")
        if isinstance(tex, TexturesVertex):
            feats = tex.verts_features_list()

            def vjp_t(g, i):
                return (Bs[i].T @ g,)

            parts = [Tensor._record(Bs[i] @ f.data, (f,), lambda g, i=i: vjp_t(g, i))
                     for i, f in enumerate(feats)]
            out.append(stack(parts))
        else:
            gm = meshes._geofit(textures=True)
            out.append(Tensor(np.stack([m.sample_textures(d.face_idx, d.bary)
                                        for m, d in zip(gm, draws)])))
    return out[0] if len(out) == 1 else tuple(out)


__getattr__ = missing_names("geofit.pytorch3d.ops", {
    "knn_points": "scipy.spatial.cKDTree(p2).query(p1, k) (geofit's chamfer uses it)",
    "knn_gather": "index the points with the indices from cKDTree.query",
    "cot_laplacian": "geofit.ops.cot_laplacian(verts, faces)",
    "laplacian": "geofit.ops.uniform_laplacian(mesh)",
    "norm_laplacian": "geofit.ops.norm_laplacian(verts, edges)",
    "packed_to_padded": "Meshes.verts_padded() or index the packed tensor",
    "sample_farthest_points": "not in the six tutorials; geofit.PointCloud.subsample(n, seed=)"
                              " draws a random subset",
})
