"""Issue 25: how far past a noisy scan's last points its fit's boundary goes (the table of
:func:`geofit.fit._cloud.boundary_distance`).

A straight rim: points of a uniform (Poisson) sampling of the half-plane ``u <= 0`` of ``z = 0``
(10,000 points a seed on a 25 x 400 strip, unit density), each moved by Gaussian noise
``sigma`` in all three axes (as the benchmark's scans are). A boundary vertex on the mean
surface (``z = 0``), at a place ``v`` along the rim, is placed as
:func:`~geofit.fit._cloud.place_boundary` places it: at the ``u`` where its nearest point is
``T`` away (by bisection here; 780 vertices spread along the rim). The clean placement is
``T = c s0`` on the noise-free points (``s0`` their spacing: median distance to the nearest
other point). For each ``sigma`` the script finds, by bisection on ``T``, the distance that
puts the vertices (on average) where the clean placement puts them, and prints it in units of
the *noisy* points' spacing ``s`` (what :class:`~geofit.fit._cloud.CloudTarget` measures)
against ``sigma / s`` (what the scan report gives): the table ``RIM_NOISE``, ``RIM_DISTANCE``.

    python benchmarks/scans_rim_offset.py --clean 2.5
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

WIDTH, LENGTH = 25.0, 400.0
ALONG = np.linspace(20.0, LENGTH - 20.0, 780)


def placement(tree: cKDTree, T: float) -> np.ndarray:
    """(780,) ``u`` of the boundary vertices whose nearest point is ``T`` away."""
    lo, hi = np.full(len(ALONG), -8.0), np.full(len(ALONG), 20.0)
    for _ in range(36):
        mid = 0.5 * (lo + hi)
        far = tree.query(np.c_[mid, ALONG, np.zeros_like(ALONG)])[0] > T
        hi, lo = np.where(far, mid, hi), np.where(far, lo, mid)
    return 0.5 * (lo + hi)


def spacing(P: np.ndarray) -> float:
    """Median distance to the nearest other point, away from the strip's ends and rim."""
    inner = (P[:, 0] < -5) & (P[:, 1] > 5) & (P[:, 1] < LENGTH - 5)
    return float(np.median(cKDTree(P).query(P[inner], 2)[0][:, 1]))


def table(clean: float, ratios, seeds=(0, 1, 2)) -> list[tuple[float, float, float]]:
    """``(sigma / s, T / s, s / s0)`` per ``sigma / s0`` of ``ratios``, averaged over seeds."""
    rows = {r: [] for r in ratios}
    for seed in seeds:
        rng = np.random.default_rng(seed)
        n = rng.poisson(WIDTH * LENGTH)
        P0 = np.c_[rng.uniform(-WIDTH, 0, n), rng.uniform(0, LENGTH, n), np.zeros(n)]
        s0 = spacing(P0)
        goal = placement(cKDTree(P0), clean * s0).mean()
        for r in ratios:
            P = P0 + rng.normal(0.0, r * s0, P0.shape)
            s, tree = spacing(P), cKDTree(P)
            lo, hi = 0.0, 12.0 * s0
            for _ in range(25):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if placement(tree, mid).mean() > goal else (mid, hi)
            rows[r].append((r * s0 / s, 0.5 * (lo + hi) / s, s / s0))
    return [tuple(np.mean(rows[r], axis=0)) for r in ratios]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clean", type=float, default=2.5,
                    help="the clean placement, in clean spacings")
    a = ap.parse_args(argv)
    ratios = [0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0]
    print("sigma/s0  sigma/s  T/s  s/s0")
    for r, (q, t, g) in zip(ratios, table(a.clean, ratios)):
        print(f"{r:7.2f} {q:8.3f} {t:6.3f} {g:6.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
