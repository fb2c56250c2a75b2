"""``torch.cuda`` without CUDA: geofit runs on the CPU (numpy, Embree, Open3D)."""
from __future__ import annotations

__all__ = ["device_count", "is_available", "set_device"]


def is_available() -> bool:
    """False: there is no CUDA here (the tutorials then take ``device("cpu")``)."""
    return False


def device_count() -> int:
    """0."""
    return 0


def set_device(device) -> None:
    """Raises: there is no CUDA device to select (the tutorials call this only when
    :func:`is_available` is True)."""
    raise RuntimeError(f"set_device: no CUDA device here (got {device!r}); geofit runs on the "
                       f"CPU, use torch.device('cpu')")
