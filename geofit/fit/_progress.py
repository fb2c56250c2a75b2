"""Progress bars of the fits (tqdm on stderr; off with ``progress=False``).

Every fit that can run for more than a few seconds shows one bar; the fits update it with their
clock paused, so drawing it is not charged to the solver.
"""
from __future__ import annotations

__all__ = ["NoBar", "progress_bar"]


class NoBar:
    """The bar of ``progress=False``: does nothing."""

    disable = True
    n = 0

    def update(self, n=1):
        pass

    def set_postfix(self, **kw):
        pass

    def close(self):
        pass


def progress_bar(enabled: bool, total: float | None, desc: str, unit: str = "it"):
    """A tqdm bar on stderr (text, also in notebooks) when ``enabled``, else :class:`NoBar`."""
    if not enabled:
        return NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, leave=False, dynamic_ncols=True)
