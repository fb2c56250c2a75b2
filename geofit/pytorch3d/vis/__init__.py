"""PyTorch3D's ``pytorch3d.vis``: the texture plot; plotly figures are not provided."""
from .texture_vis import texturesuv_image_matplotlib

__all__ = ["texturesuv_image_matplotlib"]
