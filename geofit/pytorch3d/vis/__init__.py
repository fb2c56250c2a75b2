"""PyTorch3D's ``pytorch3d.vis``: the texture plot (matplotlib) and the plotly figures."""
from .plotly_vis import AxisArgs, plot_batch_individually, plot_scene
from .texture_vis import texturesuv_image_matplotlib

__all__ = ["AxisArgs", "plot_batch_individually", "plot_scene", "texturesuv_image_matplotlib"]
