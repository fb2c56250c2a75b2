"""``pytorch3d.vis.plotly_vis``: ``plot_scene`` draws meshes, point clouds and camera centres as an
interactive plotly figure when plotly is installed (``pip install plotly``; geofit does not
depend on it). ``plot_batch_individually`` and ``AxisArgs`` are not provided."""
from __future__ import annotations

import numpy as np

from .._common import missing_names, np_

__all__ = ["plot_scene"]

_HINT = ("not provided; plot_scene({'title': {'name': meshes_or_pointclouds}}) draws each batch "
         "element as its own trace")
__getattr__ = missing_names("geofit.pytorch3d.vis.plotly_vis",
                            {"plot_batch_individually": _HINT, "AxisArgs": _HINT})


def _plotly():
    try:
        import plotly.graph_objects as go
        from plotly.subplots import make_subplots
    except ImportError:
        raise ImportError("plot_scene needs plotly (pip install plotly); without it, render "
                          "with geofit.pytorch3d.renderer.MeshRenderer (or PointsRenderer) and "
                          "show the images with matplotlib") from None
    return go, make_subplots


def _rgb(colors: np.ndarray) -> list[str]:
    c = (np.clip(np.asarray(colors, np.float64)[:, :3], 0.0, 1.0) * 255.0 + 0.5).astype(int)
    return [f"rgb({r},{g},{b})" for r, g, b in c]


def _traces(go, name: str, obj) -> list:
    """plotly traces of one object: a Meshes/Mesh (Mesh3d per element, vertex colours when
    it has them), a Pointclouds/PointCloud (Scatter3d) or cameras (their centres)."""
    if hasattr(obj, "verts_list") or hasattr(obj, "faces"):
        verts = obj.verts_list() if hasattr(obj, "verts_list") else [obj.verts]
        faces = obj.faces_list() if hasattr(obj, "faces_list") else [obj.faces]
        tex = getattr(obj, "textures", None)
        feats = None
        if tex is not None and hasattr(tex, "verts_features_list"):
            feats = tex.verts_features_list()
        elif tex is not None and hasattr(tex, "verts_features"):
            feats = [tex.verts_features]
        out = []
        for i, (v, f) in enumerate(zip(verts, faces)):
            v, f = np_(v, np.float64), np_(f, np.int64)
            kw = {"vertexcolor": _rgb(np_(feats[i]))} if feats is not None else \
                {"color": "lightgray"}
            out.append(go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1],
                                 k=f[:, 2], name=f"{name}[{i}]" if len(verts) > 1 else name,
                                 flatshading=False, **kw))
        return out
    if hasattr(obj, "points_list") or hasattr(obj, "points"):
        points = obj.points_list() if hasattr(obj, "points_list") else [obj.points]
        feats = obj.features_list() if hasattr(obj, "features_list") else \
            [getattr(obj, "features", None)]
        out = []
        for i, p in enumerate(points):
            p = np_(p, np.float64)
            f = feats[i] if feats is not None and i < len(feats) else None
            marker = {"size": 1.5}
            if f is not None:
                marker["color"] = _rgb(np_(f))
            out.append(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers",
                                    marker=marker,
                                    name=f"{name}[{i}]" if len(points) > 1 else name))
        return out
    if hasattr(obj, "get_camera_center"):
        c = np_(obj.get_camera_center(), np.float64).reshape(-1, 3)
        return [go.Scatter3d(x=c[:, 0], y=c[:, 1], z=c[:, 2], mode="markers",
                             marker={"size": 4, "symbol": "diamond"}, name=name)]
    raise TypeError(f"plot_scene: {name}: expected Meshes, Pointclouds or cameras, got "
                    f"{type(obj).__name__}")


def plot_scene(plots: dict, *, ncols: int = 1, viewpoint_cameras=None, **kwargs):
    """PyTorch3D's ``plot_scene``: one 3D subplot per key of ``plots``, each drawing its
    objects.

    Parameters
    ----------
    plots : dict of str to dict of str to object
        ``{subplot title: {trace name: Meshes, Pointclouds, Mesh, PointCloud or cameras}}``.
    ncols : int
        Subplots per row.
    viewpoint_cameras : ignored
        Accepted for PyTorch3D's call form; the figure starts at plotly's default view.
    **kwargs
        Accepted for PyTorch3D's call form (axis and marker settings) and ignored.

    Returns
    -------
    plotly.graph_objects.Figure

    Raises
    ------
    ImportError
        When plotly is not installed (with what to do instead).
    TypeError
        For ``plots`` that is not a dict of dicts, or an object of another type.
    """
    go, make_subplots = _plotly()
    if not isinstance(plots, dict) or not all(isinstance(v, dict) for v in plots.values()):
        raise TypeError(f"plots: expected a dict of dicts (subplot -> name -> object), got "
                        f"{type(plots).__name__}")
    if not isinstance(ncols, int) or ncols < 1:
        raise ValueError(f"ncols: expected an integer >= 1, got {ncols!r}")
    titles = list(plots)
    ncols = min(ncols, max(1, len(titles)))
    nrows = max(1, -(-len(titles) // ncols))
    fig = make_subplots(rows=nrows, cols=ncols, subplot_titles=titles,
                        specs=[[{"type": "scene"}] * ncols for _ in range(nrows)])
    for n, title in enumerate(titles):
        for name, obj in plots[title].items():
            for trace in _traces(go, name, obj):
                fig.add_trace(trace, row=n // ncols + 1, col=n % ncols + 1)
    fig.update_scenes(aspectmode="data")
    return fig
