"""``texturesuv_image_matplotlib``: the texture map with the UV points
(:func:`geofit.render.texturesuv_image_matplotlib`)."""
from __future__ import annotations

from ...render import utils as _ru
from ..textures import TexturesUV

__all__ = ["texturesuv_image_matplotlib"]


def texturesuv_image_matplotlib(texture: TexturesUV, *, texture_index: int = 0,
                                radius: float = 1, color=(1.0, 0.0, 0.0),
                                subsample: int | None = 10000, origin: str = "upper"):
    """Show mesh ``texture_index``'s texture map with its UV points as dots (matplotlib).

    ``origin`` is accepted for compatibility (the image is drawn with row 0 at the top).
    """
    if not isinstance(texture, TexturesUV):
        raise TypeError(f"texture: expected geofit.pytorch3d.renderer.TexturesUV, got "
                        f"{type(texture)!r}")
    return _ru.texturesuv_image_matplotlib(texture._geofit(texture_index), subsample=subsample,
                                           color=color, radius=radius * 0.01)
