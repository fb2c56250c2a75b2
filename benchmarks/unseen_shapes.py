"""Procedural analogues of the public shapes issue 24's reviewers measure and we do not have.

``benchmarks/fit_views.py --shapes unseen`` runs the default ``fit_mesh_to_views(train)`` on
them (a group of its own, not part of ``all``). Every factory is deterministic (seeded where
random) and needs no download:

- ``flat_sheet``: a zero-thickness sheet at ``z = 0`` with a wiggly, elongated outline and four
  lobes (the "flat alligator"): one open surface, one boundary loop, every ``z`` exactly 0.
- ``beetle``: an ellipsoid body and head with six two-segment legs and two antennae, capsules
  about 2 pixels thick at 128 px (thin legs); watertight, genus 0.
- ``eared_character``: head, body, arms and legs, and two tall flat ears about 1.5 pixels thick
  edge-on; watertight, genus 0.
- ``cartoon_figure``: a blobby smooth union of a big head, a body and stubby limbs, a nose and
  a deep mouth crease; watertight, genus 0.
- ``machine_part``: a rounded block with a filleted through-hole and a notch; watertight,
  genus 1.
- ``scan_blob`` (the "scanned bunny"): a bumpy blob with a deep concavity and two ears, about
  70 000 faces, vertex noise along the normals (seeded) and two small holes in its base, as a
  range scan has; genus 0 with two boundary loops.

Each returns a :class:`geofit.Mesh` in its own frame; the benchmark normalises and colours it
as the other shapes (``fit_views.vertex_coloured``).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from geofit import Mesh
from geofit.shapes import implicit_surface

__all__ = ["UNSEEN_SHAPES", "flat_sheet", "beetle", "eared_character", "cartoon_figure",
           "machine_part", "scan_blob"]


# ------------------------------------------------------------------ signed distances
def _capsule(P, a, b, r):
    a, b = np.asarray(a, float), np.asarray(b, float)
    ab = b - a
    t = np.clip((P - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(P - a - t[:, None] * ab, axis=1) - r


def _ellipsoid(P, c, radii):
    """Inigo Quilez's bound of the ellipsoid's distance (exact on its surface's zero set)."""
    q = (P - np.asarray(c, float)) / np.asarray(radii, float)
    k0 = np.linalg.norm(q, axis=1)
    k1 = np.linalg.norm(q / np.asarray(radii, float), axis=1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _smin(a, b, k):
    """Polynomial smooth minimum (a fillet of about ``k``)."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def _smax(a, b, k):
    return -_smin(-a, -b, k)


def _union(ds, k=0.0):
    out = ds[0]
    for d in ds[1:]:
        out = _smin(out, d, k) if k > 0 else np.minimum(out, d)
    return out


# ------------------------------------------------------------------ the shapes
def flat_sheet(n_interior: int = 2500, n_boundary: int = 400) -> Mesh:
    """A zero-thickness sheet at ``z = 0`` with a wiggly elongated outline (2.2 x 0.7, four
    leg lobes, a tapering tail): a unit disk's Delaunay triangulation (sunflower interior
    points and a boundary ring) mapped radially onto the outline, blended from the identity at
    the centre so that no triangle folds. Faces point to +Z."""
    k = np.arange(n_interior) + 0.5
    r = np.sqrt(k / n_interior) * (1.0 - 0.5 / np.sqrt(n_interior))
    a = k * np.pi * (3.0 - np.sqrt(5.0))
    t = 2 * np.pi * np.arange(n_boundary) / n_boundary
    xy = np.concatenate([np.stack([r * np.cos(a), r * np.sin(a)], 1),
                         np.stack([np.cos(t), np.sin(t)], 1)])
    tri = Delaunay(xy).simplices.astype(np.int64)
    th = np.arctan2(xy[:, 1], xy[:, 0])
    lobes = sum(0.45 * np.exp(-((np.angle(np.exp(1j * (th - c)))) / 0.10) ** 2)
                for c in (0.75, 2.2, -0.75, -2.2))
    R = 1.0 + lobes + 0.06 * np.sin(9 * th + 0.3) + 0.04 * np.sin(17 * th + 1.1)
    R *= 1.0 - 0.35 * np.exp(-(np.angle(np.exp(1j * (th - np.pi))) / 0.5) ** 2)  # tail
    rad = np.hypot(xy[:, 0], xy[:, 1])
    R = 1.0 + (R - 1.0) * rad  # identity at the centre, monotone along each ray (R > 1/2)
    e1, e2 = xy[tri[:, 1]] - xy[tri[:, 0]], xy[tri[:, 2]] - xy[tri[:, 0]]
    flip = (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) < 0  # counter-clockwise in the disk
    tri[flip] = tri[flip][:, ::-1]
    x = 2.2 * xy[:, 0] * R
    y = 0.7 * xy[:, 1] * R
    return Mesh(np.stack([x, y, np.zeros_like(x)], 1), tri)


def beetle(resolution: int = 128) -> Mesh:
    """An ellipsoid body and head, six two-segment legs (radius 0.028) and two antennae
    (radius 0.02), by marching cubes over ``[-1.15, 1.15]^3``."""
    def sdf(P):
        ds = [_ellipsoid(P, (0.0, 0.0, 0.0), (0.55, 0.36, 0.24)),
              _ellipsoid(P, (0.62, 0.0, 0.02), (0.18, 0.17, 0.13))]
        for sx in (-0.3, 0.0, 0.3):  # legs: out and up, then down to the ground
            for sy in (-1.0, 1.0):
                hip = (sx, 0.25 * sy, -0.05)
                knee = (sx * 1.5 + 0.05, 0.62 * sy, 0.18)
                foot = (sx * 1.9 + 0.08 * np.sign(sx), 0.85 * sy, -0.42)
                ds += [_capsule(P, hip, knee, 0.028), _capsule(P, knee, foot, 0.028)]
        for sy in (-1.0, 1.0):
            ds.append(_capsule(P, (0.74, 0.06 * sy, 0.08), (1.05, 0.38 * sy, 0.3), 0.02))
        return _union(ds, 0.02)

    return implicit_surface(sdf, 1.15, resolution)


def eared_character(resolution: int = 140) -> Mesh:
    """Head, body, arms and legs with two tall flat ears (0.035 thick), by marching cubes."""
    def sdf(P):
        ds = [_ellipsoid(P, (0.0, 0.35, 0.0), (0.3, 0.28, 0.27)),
              _ellipsoid(P, (0.0, -0.2, 0.0), (0.26, 0.33, 0.22)),
              _capsule(P, (-0.2, -0.05, 0.0), (-0.45, -0.35, 0.1), 0.06),
              _capsule(P, (0.2, -0.05, 0.0), (0.45, -0.35, 0.1), 0.06),
              _capsule(P, (-0.12, -0.45, 0.0), (-0.15, -0.85, 0.05), 0.08),
              _capsule(P, (0.12, -0.45, 0.0), (0.15, -0.85, 0.05), 0.08)]
        body = _union(ds, 0.06)
        ears = []
        for s in (-1.0, 1.0):  # tilted outwards by 15 degrees about z
            c, sn = np.cos(np.radians(15)), s * np.sin(np.radians(15))
            q = P - np.array([0.15 * s, 0.85, 0.0])
            q = np.stack([c * q[:, 0] + sn * q[:, 1], -sn * q[:, 0] + c * q[:, 1], q[:, 2]], 1)
            ears.append(_ellipsoid(q, (0.0, 0.0, 0.0), (0.09, 0.33, 0.0175)))
        return _smin(body, np.minimum(*ears), 0.03)

    return implicit_surface(sdf, 1.3, resolution)


def cartoon_figure(resolution: int = 120) -> Mesh:
    """A blobby figure: a big head with a nose and a deep mouth crease, a body and stubby
    limbs (smooth union), by marching cubes."""
    def sdf(P):
        head = _ellipsoid(P, (0.0, 0.35, 0.0), (0.45, 0.42, 0.4))
        nose = _ellipsoid(P, (0.0, 0.3, 0.42), (0.09, 0.08, 0.12))
        body = _ellipsoid(P, (0.0, -0.35, 0.0), (0.32, 0.35, 0.28))
        limbs = [_capsule(P, (sx * 0.25, -0.2, 0.0), (sx * 0.6, -0.05, 0.15), 0.09)
                 for sx in (-1, 1)]
        limbs += [_capsule(P, (sx * 0.15, -0.6, 0.0), (sx * 0.2, -0.9, 0.12), 0.1)
                  for sx in (-1, 1)]
        d = _union([head, body, *limbs], 0.08)
        d = _smin(d, nose, 0.03)
        mouth = _capsule(P, (-0.2, 0.12, 0.4), (0.2, 0.12, 0.4), 0.05)  # a crease cut in
        return _smax(d, -mouth, 0.02)

    return implicit_surface(sdf, 1.1, resolution)


def machine_part(resolution: int = 120) -> Mesh:
    """A rounded 1.6 x 0.5 x 1.0 block with a filleted through-hole (radius 0.25, along y)
    and a notch cut in one end; genus 1."""
    half = np.array([0.8, 0.25, 0.5])
    rr = 0.06

    def sdf(P):
        q = np.abs(P) - (half - rr)
        block = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0) - rr
        hole = np.hypot(P[:, 0] + 0.25, P[:, 2]) - 0.25
        nq = np.abs(P - np.array([0.8, 0.0, 0.0])) - np.array([0.25, 0.4, 0.15])
        notch = np.linalg.norm(np.maximum(nq, 0.0), axis=1) + np.minimum(nq.max(axis=1), 0.0)
        return _smax(_smax(block, -hole, 0.05), -notch, 0.03)

    return implicit_surface(sdf, 1.0, resolution)


def scan_blob(resolution: int = 144, noise: float = 0.002, seed: int = 0) -> Mesh:
    """A bunny-like scan: a bumpy blob with a deep concavity and two ears, about 70 000
    faces by marching cubes, Gaussian vertex noise of ``noise`` along the normals (seeded) and
    two small holes in its base (open boundaries)."""
    def sdf(P):
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        bumps = 0.03 * (np.sin(7 * x + 1) * np.sin(6 * y + 2) * np.sin(8 * z)
                        + 0.6 * np.sin(13 * x - 4 * z + 0.5) * np.sin(11 * y + 1.3))
        body = _ellipsoid(P, (0.0, -0.1, 0.0), (0.7, 0.55, 0.5)) + bumps
        head = _ellipsoid(P, (0.45, 0.35, 0.0), (0.3, 0.26, 0.25))
        ears = [_ellipsoid(P, (0.35, 0.72, 0.12 * s), (0.07, 0.3, 0.05)) for s in (-1, 1)]
        d = _union([body, head, *ears], 0.08)
        cave = _ellipsoid(P, (-0.2, -0.05, 0.5), (0.3, 0.25, 0.32))  # the deep concavity
        return _smax(d, -cave, 0.05)

    m = implicit_surface(sdf, 1.05, resolution)
    V, F = m.verts, m.faces
    # two holes in the base: drop the faces whose centroid is within 0.08 of two points
    c = V[F].mean(axis=1)
    drop = np.zeros(len(F), bool)
    for h in ((0.1, -0.65, 0.1), (-0.3, -0.6, -0.15)):
        drop |= np.linalg.norm(c - np.asarray(h), axis=1) < 0.08
    F = F[~drop]
    used = np.unique(F)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    m = Mesh(V[used], remap[F])
    n = m.verts_normals
    rng = np.random.default_rng(seed)
    return Mesh(m.verts + noise * rng.standard_normal(len(m.verts))[:, None] * n, m.faces)


#: name -> factory (no arguments), in the order of the table.
UNSEEN_SHAPES = {
    "flat_sheet": flat_sheet,
    "beetle": beetle,
    "eared_character": eared_character,
    "cartoon_figure": cartoon_figure,
    "machine_part": machine_part,
    "scan_blob": scan_blob,
}
