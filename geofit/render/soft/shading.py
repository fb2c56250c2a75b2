"""Phong shading of vertex colours on soft fragments (PyTorch3D's ``SoftPhongShader`` with
``TexturesVertex``), with the vjp to positions (through distances, barycentrics, depths and
the shading normals) and to colours (linear; :meth:`PhongColors` as sparse matrices).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..._validate import as_array
from ...structures import Mesh
from ..lighting import AmbientLights, DirectionalLights, PointLights
from .fragments import _NORM_EPS, SoftFragments, _check_fragments, _map_views
from .rasterizer import _check_cameras, _check_mesh

__all__ = [
    "PhongColors",
    "phong_vertex_colors",
]

# ------------------------------------------------------------------------------------------
# Phong shading of vertex colours
# ------------------------------------------------------------------------------------------


def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _normalize3(x):
    """x / max(|x|, 1e-6) for a vector given as three (m,) components; also |x| and the divisor."""
    nrm = np.sqrt(_dot3(x, x))
    c = np.maximum(nrm, _NORM_EPS)
    inv = 1.0 / c
    return [xi * inv for xi in x], nrm, c


def _normalize3_vjp(g, y, nrm, c):
    """Backward of y = x / max(|x|, eps) (the clamp passes no gradient to |x|)."""
    proj = np.where(nrm > _NORM_EPS, _dot3(y, g), 0.0)
    inv = 1.0 / c
    return [(g[i] - y[i] * proj) * inv for i in range(3)]


def _vertex_normals(verts: np.ndarray, faces: np.ndarray):
    """PyTorch3D's vertex normals (component arrays) and what their vjp needs."""
    V = len(verts)
    X = [np.ascontiguousarray(verts[:, c]) for c in range(3)]
    f0, f1, f2 = (np.ascontiguousarray(faces[:, i]) for i in range(3))
    a = [X[c][f1] - X[c][f0] for c in range(3)]
    b = [X[c][f2] - X[c][f0] for c in range(3)]
    cr = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    m = [np.bincount(f0, cr[c], V) + np.bincount(f1, cr[c], V) + np.bincount(f2, cr[c], V)
         for c in range(3)]
    n, nrm, cl = _normalize3(m)
    return n, (a, b, nrm, cl, f0, f1, f2)


def _vertex_normals_vjp(g_n, n, saved, V):
    a, b, nrm, cl, f0, f1, f2 = saved
    g_m = _normalize3_vjp(g_n, n, nrm, cl)
    g_c = [g_m[c][f0] + g_m[c][f1] + g_m[c][f2] for c in range(3)]
    # cross = a x b: d/da = b x g, d/db = g x a
    g_a = [b[1] * g_c[2] - b[2] * g_c[1], b[2] * g_c[0] - b[0] * g_c[2],
           b[0] * g_c[1] - b[1] * g_c[0]]
    g_b = [g_c[1] * a[2] - g_c[2] * a[1], g_c[2] * a[0] - g_c[0] * a[2],
           g_c[0] * a[1] - g_c[1] * a[0]]
    out = np.empty((V, 3))
    for c in range(3):  # coordinates
        out[:, c] = (np.bincount(f1, g_a[c], V) + np.bincount(f2, g_b[c], V)
                     - np.bincount(f0, g_a[c] + g_b[c], V))
    return out


def _per_view(param: np.ndarray, n_views: int, name: str) -> np.ndarray:
    p = np.asarray(param, dtype=np.float64)
    if p.shape[0] not in (1, n_views):
        raise ValueError(f"{name}: expected 1 or {n_views} entries (one per view), got "
                         f"{p.shape[0]}")
    return np.broadcast_to(p, (n_views,) + p.shape[1:])


def _entry_param(p: np.ndarray, view: np.ndarray):
    """Per-entry values of a per-view parameter (N,) or (N, 3): scalars when all views agree."""
    if p.ndim == 1:
        return float(p[0]) if np.all(p == p[0]) else p[view]
    if np.all(p == p[0]):
        return [float(v) for v in p[0]]
    return [np.ascontiguousarray(p[view, c]) for c in range(p.shape[1])]


def _interp(b, cols, i):
    """sum_j b_j cols[c][i_j] for each component c."""
    return [b[0] * col[i[0]] + b[1] * col[i[1]] + b[2] * col[i[2]] for col in cols]


def _scatter(b, g, i, V):
    """(V, 3): sum over entries of b_j g[c] onto vertex i_j (the transpose of _interp)."""
    out = np.empty((V, len(g)))
    for c in range(len(g)):  # components
        out[:, c] = (np.bincount(i[0], b[0] * g[c], V) + np.bincount(i[1], b[1] * g[c], V)
                     + np.bincount(i[2], b[2] * g[c], V))
    return out


_CHUNK = 32768  # entries per shading chunk (cache-sized arrays; ~60 float64 temporaries each)


def _chunks(n: int, size: int = _CHUNK) -> list:
    return [slice(a, min(a + size, n)) for a in range(0, n, size)]


@dataclass(eq=False)
class PhongColors:
    """Per-entry Phong colours of :func:`phong_vertex_colors` and what their vjp needs.

    Attributes
    ----------
    entries : (k,) int64
        The fragment entries shaded (all of them unless a subset was asked for).
    colors : (k, 3) float64
        ``(Ma La + Md D) texel + Ms S`` per shaded entry.
    shade : (k, 3) float64
        ``Ma La + Md D``: the factor multiplying the interpolated vertex colour.
    specular : (k, 3) float64
        ``Ms S``.
    """

    entries: np.ndarray
    colors: np.ndarray
    shade: np.ndarray
    specular: np.ndarray
    _saved: dict = field(default_factory=dict, repr=False)

    @property
    def cos(self) -> np.ndarray:
        """(k,) float64 ``n . l`` (cosine between the shading normal and the light) per entry."""
        s = self._saved
        parts = [s["chunk"](ci)[3]["cos"] for ci in range(len(s["chunks"]))]  # chunks
        return np.concatenate(parts) if parts else np.zeros(0)

    def vjp(self, grad_colors) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Backward of the shading.

        Parameters
        ----------
        grad_colors : (k, 3) float64
            dL/d ``colors``.

        Returns
        -------
        grad_verts : (V, 3) float64
            Through the interpolated world positions and the vertex normals (not through the
            barycentrics: see ``grad_bary``).
        grad_vertex_colors : (V, 3) float64
        grad_bary : (k, 3) float64
            dL/d barycentrics of the shaded entries (for :meth:`SoftFragments.vjp`).
        """
        s = self._saved
        k = len(self.entries)
        dt = self.colors.dtype
        keep = isinstance(grad_colors, np.ndarray) and grad_colors.dtype == dt
        g = as_array(grad_colors, "grad_colors", (k, 3), dt if keep else np.float64)
        V = s["n_verts"]
        g_bary = np.empty((k, 3), dt)

        def one(ci):
            sl = s["chunks"][ci]
            # the chunk's intermediates are recomputed (exactly as in the forward pass) rather
            # than kept: they would be ~25 float64 arrays per shaded entry
            gP, gN, gT, gb, cs = _phong_chunk_vjp(s["chunk"](ci)[3], g[sl].astype(np.float64),
                                                  self.shade[sl].astype(np.float64), s)
            g_bary[sl] = gb
            b, i = cs["b"], cs["i"]
            return _scatter(b, gP, i, V), _scatter(b, gN, i, V), _scatter(b, gT, i, V)

        parts = _map_views(one, len(s["chunks"]), s["n_threads"])
        gv = np.zeros((V, 3))
        gn = np.zeros((V, 3))
        gcol = np.zeros((V, 3))
        for a, b, c in parts:  # chunks
            gv += a
            gn += b
            gcol += c
        gv += _vertex_normals_vjp([np.ascontiguousarray(gn[:, c]) for c in range(3)], s["vn"],
                                  s["vn_saved"], V)
        return gv, gcol, g_bary


def _phong_chunk(b, i, v, s):
    """Phong colours of one chunk of entries (barycentrics b, vertex ids i, views v)."""
    P = _interp(b, s["verts"], i)
    Nrm = _interp(b, s["vn"], i)
    tex = _interp(b, s["vcol"], i)
    nn, *n_norm = _normalize3(Nrm)
    if s["loc"] is not None:
        lp = _entry_param(s["loc"], v)
        Lraw = [lp[c] - P[c] for c in range(3)]
    elif s["direction"] is not None:
        dp = _entry_param(s["direction"], v)
        Lraw = [np.broadcast_to(np.asarray(dp[c], np.float64), P[0].shape) for c in range(3)]
    else:
        Lraw = [np.zeros_like(P[0]) for _ in range(3)]
    ln, *l_norm = _normalize3(Lraw)
    cos = _dot3(nn, ln)
    cp = _entry_param(s["centres"], v)
    vd, *v_norm = _normalize3([cp[c] - P[c] for c in range(3)])
    r = [2.0 * cos * nn[c] - ln[c] for c in range(3)]
    alpha = np.where(cos > 0.0, np.maximum(_dot3(vd, r), 0.0), 0.0)
    sh = _entry_param(s["shininess"], v)
    pw = np.power(alpha, sh)
    Ld, Ls = _entry_param(s["Ld"], v), _entry_param(s["Ls"], v)
    La, Ma, Md, Ms = (_entry_param(s[k], v) for k in ("La", "Ma", "Md", "Ms"))
    relu = np.maximum(cos, 0.0)
    n = len(cos)
    shade = np.empty((n, 3))
    spec = np.empty((n, 3))
    colors = np.empty((n, 3))
    for c in range(3):  # colour channels
        shade[:, c] = Ma[c] * La[c] + Md[c] * (Ld[c] * relu)
        spec[:, c] = Ms[c] * (Ls[c] * pw)
        colors[:, c] = shade[:, c] * tex[c] + spec[:, c]
    saved = {"b": b, "i": i, "Md": Md, "Ms": Ms, "Ld": Ld, "Ls": Ls, "tex": tex, "cos": cos,
             "alpha": alpha, "shininess": sh, "nn": nn, "l": ln, "v": vd, "r": r,
             "l_norm": l_norm, "v_norm": v_norm, "n_norm": n_norm}
    return colors, shade, spec, saved


def _phong_chunk_vjp(cs, g, shade, s):
    """Gradients on the interpolated position, normal and texel, and on the barycentrics."""
    g = [np.ascontiguousarray(g[:, c]) for c in range(3)]
    i = cs["i"]
    g_tex = [g[c] * shade[:, c] for c in range(3)]
    vcol = s["vcol"]
    g_bary = [g_tex[0] * vcol[0][i[j]] + g_tex[1] * vcol[1][i[j]] + g_tex[2] * vcol[2][i[j]]
              for j in range(3)]
    Md, Ld, Ms, Ls = cs["Md"], cs["Ld"], cs["Ms"], cs["Ls"]
    tex, cos = cs["tex"], cs["cos"]
    # diffuse = Ld max(0, cos): d colour_c / d cos = Md_c Ld_c texel_c [cos > 0]
    g_cos = (g[0] * (Md[0] * Ld[0]) * tex[0] + g[1] * (Md[1] * Ld[1]) * tex[1]
             + g[2] * (Md[2] * Ld[2]) * tex[2]) * (cos > 0.0)
    # specular = Ls alpha^sh with alpha = max(r . v, 0) [cos > 0]
    a, sh = cs["alpha"], cs["shininess"]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        da = np.where(a > 0.0, sh * np.power(a, sh - 1.0), 0.0)
    g_a = (g[0] * (Ms[0] * Ls[0]) + g[1] * (Ms[1] * Ls[1]) + g[2] * (Ms[2] * Ls[2])) * da
    nn, ln, vd, r = cs["nn"], cs["l"], cs["v"], cs["r"]
    g_r = [g_a * vd[c] for c in range(3)]
    g_v = [g_a * r[c] for c in range(3)]
    # r = 2 cos nn - l with cos = nn . l
    g_cos = g_cos + 2.0 * _dot3(g_r, nn)
    g_nn = [2.0 * cos * g_r[c] + g_cos * ln[c] for c in range(3)]
    g_l = [g_cos * nn[c] - g_r[c] for c in range(3)]
    gv_raw = _normalize3_vjp(g_v, vd, *cs["v_norm"])
    g_P = [-x for x in gv_raw]
    if s["loc"] is not None:  # l = normalize(location - P)
        gl_raw = _normalize3_vjp(g_l, ln, *cs["l_norm"])
        g_P = [g_P[c] - gl_raw[c] for c in range(3)]
    g_N = _normalize3_vjp(g_nn, nn, *cs["n_norm"])
    # P = sum b_j V[i_j], N = sum b_j n[i_j]
    Vc, Nc = s["verts"], s["vn"]
    for j in range(3):  # corners
        g_bary[j] = g_bary[j] + (g_P[0] * Vc[0][i[j]] + g_P[1] * Vc[1][i[j]]
                                 + g_P[2] * Vc[2][i[j]] + g_N[0] * Nc[0][i[j]]
                                 + g_N[1] * Nc[1][i[j]] + g_N[2] * Nc[2][i[j]])
    return g_P, g_N, g_tex, np.stack(g_bary, 1), cs


def _light_params(lights, n_views):
    if not isinstance(lights, (PointLights, DirectionalLights, AmbientLights)):
        raise TypeError(f"lights: expected PointLights, DirectionalLights or AmbientLights, got "
                        f"{type(lights)!r}")
    amb = _per_view(lights.ambient_color, n_views, "lights.ambient_color")
    if isinstance(lights, AmbientLights):
        zero = np.zeros((n_views, 3))
        return amb, zero, zero, None, None
    dif = _per_view(lights.diffuse_color, n_views, "lights.diffuse_color")
    spe = _per_view(lights.specular_color, n_views, "lights.specular_color")
    if isinstance(lights, PointLights):
        return amb, dif, spe, _per_view(lights.location, n_views, "lights.location"), None
    return amb, dif, spe, None, _per_view(lights.direction, n_views, "lights.direction")


def shading_state(mesh: Mesh, vcol: np.ndarray, lights, cameras, materials, n_views: int,
                  n_threads: int = 1) -> dict:
    """What :func:`_phong_chunk` and its vjp read: the mesh's coordinates, PyTorch3D's vertex
    normals (and what their vjp needs), the vertex colours and the per-view light, material and
    camera parameters (the one place the soft and the hard image terms take them from)."""
    N = n_views
    V = mesh.n_verts
    amb, dif, spe, loc, direction = _light_params(lights, N)
    vn, vn_saved = _vertex_normals(mesh.verts, mesh.faces)
    return {"n_verts": V, "verts": [np.ascontiguousarray(mesh.verts[:, c]) for c in range(3)],
            "vn": vn, "vn_saved": vn_saved,
            "vcol": [np.ascontiguousarray(vcol[:, c]) for c in range(3)],
            "loc": loc, "direction": direction, "La": amb, "Ld": dif, "Ls": spe,
            "Ma": _per_view(materials.ambient_color, N, "materials.ambient_color"),
            "Md": _per_view(materials.diffuse_color, N, "materials.diffuse_color"),
            "Ms": _per_view(materials.specular_color, N, "materials.specular_color"),
            "shininess": _per_view(materials.shininess, N, "materials.shininess"),
            "centres": _per_view(cameras.get_camera_center(), N, "cameras"),
            "n_threads": n_threads}


def phong_vertex_colors(fragments: SoftFragments, mesh: Mesh, vertex_colors, lights, cameras,
                        materials, entries=None) -> PhongColors:
    """Per-entry Phong colours of a mesh with per-vertex colours (PyTorch3D's ``phong_shading``).

    For each fragment entry with (clipped) barycentrics ``b``: world point ``P = sum b_i v_i``,
    normal ``N = sum b_i n_i`` (``n`` PyTorch3D's area-weighted vertex normals), texel
    ``t = sum b_i c_i``; then ``colour = (Ma La + Md Ld max(0, n.l)) t + Ms Ls max(0, r.v)^s
    [n.l > 0]`` with ``n = N/|N|``, ``l`` towards the light, ``v`` towards the camera and
    ``r = 2 (n.l) n - l`` (normalisations with eps 1e-6). No attenuation or shadows.

    Parameters
    ----------
    fragments : SoftFragments
        From :func:`rasterize_soft` of ``mesh``.
    mesh : Mesh
        The rasterized mesh (``V`` vertices).
    vertex_colors : (V, 3) float64
        Per-vertex RGB.
    lights : PointLights, DirectionalLights or AmbientLights
        1 or N lights.
    cameras : camera batch
        The N cameras (their centres give the view directions).
    materials : Materials
        1 or N materials.
    entries : (k,) int64, optional
        Shade only these fragment entries (default: all).

    Returns
    -------
    PhongColors
        Computed in cache-sized chunks on the fragments' thread count.
    """
    fr = _check_fragments(fragments)
    mesh = _check_mesh(mesh)
    cameras = _check_cameras(cameras)
    V = mesh.n_verts
    vcol = as_array(vertex_colors, "vertex_colors", (V, 3))
    if fr._ctx.get("n_verts") != V:
        raise ValueError(f"fragments: rasterized from a mesh with {fr._ctx.get('n_verts')} "
                         f"vertices, mesh has {V}")
    N = fr.n_views
    if len(cameras) not in (1, N):
        raise ValueError(f"cameras: expected 1 or {N} cameras, got {len(cameras)}")
    if entries is None:
        entries = np.arange(len(fr))
    else:
        entries = as_array(entries, "entries", (None,), np.int64)
        if entries.size and (entries.min() < 0 or entries.max() >= len(fr)):
            raise ValueError(f"entries: expected indices in [0, {len(fr)}), got range "
                             f"[{entries.min()}, {entries.max()}]")
    s = shading_state(mesh, vcol, lights, cameras, materials, N, fr._ctx.get("n_threads", 1))
    k = len(entries)
    chunks = _chunks(k)
    dtype = fr.dist.dtype
    colors = np.empty((k, 3), dtype)
    shade = np.empty((k, 3), dtype)
    spec = np.empty((k, 3), dtype)
    faces = mesh.faces
    bary = fr.bary

    def chunk(ci):
        e = entries[chunks[ci]]
        tri = faces[fr.face[e]]
        i = [np.ascontiguousarray(tri[:, j]) for j in range(3)]
        bb = bary[e]
        b = [np.ascontiguousarray(bb[:, j], dtype=np.float64) for j in range(3)]
        return _phong_chunk(b, i, fr.view[e], s)

    def one(ci):
        c, sh, sp, _ = chunk(ci)
        colors[chunks[ci]], shade[chunks[ci]], spec[chunks[ci]] = c, sh, sp

    _map_views(one, len(chunks), s["n_threads"])
    s["chunk"] = chunk
    s["chunks"] = chunks
    return PhongColors(entries, colors, shade, spec, s)
