"""Progress bars of the fits (tqdm.auto: widgets in notebooks, stderr in terminals; off with
``progress=False``).

Every fit that can run for more than a few seconds shows one bar; the fits update it with their
clock paused, so drawing it is not charged to the solver.
"""
from __future__ import annotations

__all__ = ["NoBar", "advance", "progress_bar"]


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


#: The look of a bar counting seconds of a time budget: "fit_nerf: 41%|####   | 3.3 s / 8.0 s"
#: (tqdm's default would read "3.29/8.0 [00:05<00:07, 1.26s/s]").
TIME_BAR = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f} s / {total:.1f} s{postfix}"


def progress_bar(enabled: bool, total: float | None, desc: str, unit: str = "it"):
    """A tqdm bar when ``enabled``, else :class:`NoBar`: ``tqdm.auto`` (a widget in a notebook,
    text on stderr in a terminal); ``unit="s"`` counts seconds of a time budget
    (:data:`TIME_BAR`)."""
    if not enabled:
        return NoBar()
    from tqdm.auto import tqdm

    fmt = {"bar_format": TIME_BAR} if unit == "s" and total is not None else {}
    return tqdm(total=total, desc=desc, unit=unit, leave=False, dynamic_ncols=True, **fmt)


def advance(bar, clock, postfix: dict | None = None) -> None:
    """One step of ``bar`` (and its ``postfix`` fields, when given) drawn with ``clock`` paused,
    so drawing is not charged to the fit."""
    with clock.paused():
        bar.update(1)
        if postfix is not None:
            bar.set_postfix(**postfix)
