"""PyTorch3D's ``pytorch3d.vis.plotly_vis``: ``plot_scene``, ``plot_batch_individually``,
``AxisArgs`` (interactive 3D figures with plotly, when it is installed).

Meshes become ``Mesh3d`` traces (vertex colours from ``TexturesVertex``; other textures and
none: plotly's default colour), point clouds ``Scatter3d`` markers (colours from their
features), cameras wireframe ``Scatter3d`` lines. plotly is imported when a figure is made:
without it the call raises ImportError saying ``pip install plotly``.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...structures import Mesh, PointCloud
from ...structures import TexturesVertex as _GeofitTexturesVertex
from ..structures import Meshes, Pointclouds
from ..textures import TexturesVertex

__all__ = ["AxisArgs", "plot_batch_individually", "plot_scene"]


class AxisArgs(NamedTuple):
    """Axis settings of every subplot (PyTorch3D's defaults: a bare white scene)."""

    showgrid: bool = False
    zeroline: bool = False
    showline: bool = False
    ticks: str = ""
    showticklabels: bool = False
    backgroundcolor: str = "#fff"
    showaxeslabels: bool = False


def _plotly():
    try:
        import plotly.graph_objects as go
        from plotly.subplots import make_subplots
    except ImportError:  # pragma: no cover - plotly is in the test extra
        raise ImportError("plot_scene / plot_batch_individually need plotly: pip install plotly "
                          "(or render with geofit.pytorch3d.renderer and show the images with "
                          "matplotlib)") from None
    return go, make_subplots


def _arr(x) -> np.ndarray:
    return np.asarray(getattr(x, "data", x), np.float64)


def _rgb(c: np.ndarray) -> list:
    c = np.clip(np.nan_to_num(c[:, :3]), 0.0, 1.0) * 255.0
    return [f"rgb({r:.0f},{g:.0f},{b:.0f})" for r, g, b in c]


def _mesh_trace(go, m: Meshes, name: str):
    verts = [_arr(v) for v in m.verts_list()]
    faces, start = [], 0
    for v, f in zip(verts, m.faces_list()):  # batch members, joined into one trace
        faces.append(_arr(f).astype(np.int64) + start)
        start += len(v)
    V, F = np.concatenate(verts), np.concatenate(faces)
    kw = {}
    if isinstance(m.textures, TexturesVertex):
        kw["vertexcolor"] = _rgb(_arr(m.textures.verts_features_packed()))
    return go.Mesh3d(x=V[:, 0], y=V[:, 1], z=V[:, 2], i=F[:, 0], j=F[:, 1], k=F[:, 2],
                     name=name, **kw)


def _cloud_trace(go, pc: Pointclouds, name: str, max_points: int, marker_size: float):
    P = _arr(pc.points_packed())
    feats = pc.features_packed()
    keep = np.arange(len(P))
    if len(P) > max_points:  # PyTorch3D subsamples large clouds too
        keep = np.random.default_rng(0).choice(len(P), max_points, replace=False)
    marker = {"size": marker_size}
    if feats is not None:
        marker["color"] = _rgb(_arr(feats)[keep])
    return go.Scatter3d(x=P[keep, 0], y=P[keep, 1], z=P[keep, 2], mode="markers",
                        marker=marker, name=name)


def _camera_trace(go, cameras, name: str, scale: float):
    """A wireframe pyramid per camera, from its centre towards +Z of its view."""
    R = _arr(cameras.R)
    T = _arr(cameras.T)
    s = scale
    local = np.array([[0, 0, 0], [-s, -s, 2 * s], [s, -s, 2 * s], [s, s, 2 * s], [-s, s, 2 * s]])
    lines = [0, 1, 2, 0, 2, 3, 0, 3, 4, 0, 4, 1]
    # view X = world X R + T  ->  world X = (view X - T) R^T
    pts = np.einsum("nkj,nij->nki", local[None] - T[:, None, :], R)
    seg = np.concatenate([np.concatenate([p[lines], np.full((1, 3), np.nan)]) for p in pts])
    return go.Scatter3d(x=seg[:, 0], y=seg[:, 1], z=seg[:, 2], mode="lines", name=name)


def _from_geofit(obj):
    """geofit's own Mesh / PointCloud as the PyTorch3D structures drawn here (vertex colours
    and point features kept)."""
    if isinstance(obj, Mesh):
        tex = obj.textures
        colours = (TexturesVertex(verts_features=[tex.verts_features])
                   if isinstance(tex, _GeofitTexturesVertex) else None)
        return Meshes(verts=[obj.verts], faces=[obj.faces], textures=colours)
    if isinstance(obj, PointCloud):
        feats = None if obj.features is None else [obj.features]
        return Pointclouds(points=[obj.points], features=feats)
    return obj


def _trace(go, obj, name: str, kw: dict):
    obj = _from_geofit(obj)
    if isinstance(obj, Meshes):
        return _mesh_trace(go, obj, name)
    if isinstance(obj, Pointclouds):
        return _cloud_trace(go, obj, name, kw["pointcloud_max_points"],
                            kw["pointcloud_marker_size"])
    if hasattr(obj, "R") and hasattr(obj, "T"):
        return _camera_trace(go, obj, name, kw["camera_scale"])
    raise TypeError(f"plot_scene: {name!r} is a {type(obj)!r}; expected Meshes, Pointclouds or "
                    f"cameras (geofit's Mesh and PointCloud too)")


def plot_scene(plots: dict, *, viewpoint_cameras=None, ncols: int = 1,
               camera_scale: float = 0.3, pointcloud_max_points: int = 20000,
               pointcloud_marker_size: float = 1, axis_args: AxisArgs | None = None, **kwargs):
    """A plotly figure with one 3D subplot per key of ``plots`` (PyTorch3D's ``plot_scene``).

    Parameters
    ----------
    plots : dict of str -> dict of str -> Meshes, Pointclouds or cameras
        ``{subplot title: {trace name: structure}}``; a batch in one entry is one trace.
    viewpoint_cameras : cameras, optional
        Accepted for PyTorch3D's signature; the figure opens with plotly's default view.
    ncols : int
        Subplots per row.
    camera_scale, pointcloud_max_points, pointcloud_marker_size
        Size of camera wireframes, largest number of points drawn per cloud, marker size.
    axis_args : AxisArgs, optional
        Settings of the three axes.
    **kwargs
        ``xaxis``, ``yaxis``, ``zaxis``: dicts merged into each axis' settings.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    if not isinstance(plots, dict) or not all(isinstance(v, dict) for v in plots.values()):
        raise TypeError("plots: expected a dict {subplot title: {trace name: structure}}")
    go, make_subplots = _plotly()
    ncols = max(1, min(int(ncols), len(plots)))
    nrows = -(-len(plots) // ncols)
    fig = make_subplots(rows=nrows, cols=ncols, subplot_titles=list(plots),
                        specs=[[{"type": "scene"}] * ncols for _ in range(nrows)])
    axis = (axis_args or AxisArgs())._asdict()
    opts = {"camera_scale": camera_scale, "pointcloud_max_points": pointcloud_max_points,
            "pointcloud_marker_size": pointcloud_marker_size}
    for i, traces in enumerate(plots.values()):  # subplots
        for name, obj in traces.items():  # traces of the subplot
            fig.add_trace(_trace(go, obj, name, opts), row=i // ncols + 1, col=i % ncols + 1)
        scene = {a: {**axis, **kwargs.get(a, {})} for a in ("xaxis", "yaxis", "zaxis")}
        scene["aspectmode"] = "data"
        fig.update_layout({f"scene{'' if i == 0 else i + 1}": scene})
    return fig


def plot_batch_individually(batched_structs, *, viewpoint_cameras=None, ncols: int = 1,
                            extend_struct: bool = True, subplot_titles=None, **kwargs):
    """One subplot per batch member (PyTorch3D's ``plot_batch_individually``).

    Parameters
    ----------
    batched_structs : Meshes, Pointclouds or cameras, or a list of them
        Member ``i`` of each goes into subplot ``i``; with ``extend_struct`` a batch of one is
        drawn in every subplot.
    subplot_titles : list of str, optional
        Default ``"subplot 1"``, ...
    ncols, viewpoint_cameras, **kwargs
        As :func:`plot_scene`.
    """
    structs = batched_structs if isinstance(batched_structs, (list, tuple)) else \
        [batched_structs]
    n = max(len(s) for s in structs)
    titles = subplot_titles or [f"subplot {i + 1}" for i in range(n)]
    if len(titles) != n:
        raise ValueError(f"subplot_titles: expected {n} titles, got {len(titles)}")
    plots = {}
    for i, title in enumerate(titles):  # batch members
        plots[title] = {f"trace{j + 1}-{i}": (s[i] if len(s) > 1 or not extend_struct else s[0])
                        for j, s in enumerate(structs) if i < len(s) or extend_struct}
    return plot_scene(plots, viewpoint_cameras=viewpoint_cameras, ncols=ncols, **kwargs)
