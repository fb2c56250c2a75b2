"""``pytorch3d.vis.plotly_vis`` is not provided (geofit has no plotly dependency)."""
from .._common import missing_names

__all__: list = []

_HINT = ("plotly figures are not provided; render with geofit.pytorch3d.renderer.MeshRenderer "
         "(or PointsRenderer) and show the images with matplotlib, or open an interactive "
         "viewer with geofit.render.open3d.show_open3d(mesh, cameras)")
__getattr__ = missing_names("geofit.pytorch3d.vis.plotly_vis",
                            {"plot_scene": _HINT, "plot_batch_individually": _HINT,
                             "AxisArgs": _HINT})
