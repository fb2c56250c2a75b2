"""Figures every geofit benchmark and report shares: one chart style, image panels, PNG output.

* :data:`STYLE` and :func:`chart_style` -- the matplotlib settings of every chart (the benchmark
  harness in ``benchmarks/_harness.py`` and ``geofit tutorials`` both draw with them, so their
  charts look alike and can be compared).
* :func:`plot_accuracy_vs_time` -- accuracy against wall time, one panel per metric, one curve
  per method (log time axis).
* :func:`plot_model_sizes` -- parameter counts as horizontal bars (log axis).
* :func:`to_uint8`, :func:`save_png` and :func:`image_panel` -- images to PNG, and labelled
  grids of images (targets next to results) drawn with Pillow, pixel for pixel.

Charts are written with matplotlib's Agg backend (no display needed).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ._atomic import atomic_write
from ._validate import as_array

__all__ = [
    "STYLE",
    "Series",
    "Table",
    "chart_style",
    "image_panel",
    "plot_accuracy_vs_time",
    "plot_model_sizes",
    "save_png",
    "to_uint8",
]

#: The matplotlib rc settings of every geofit chart.
STYLE: dict[str, Any] = {
    "figure.dpi": 110, "savefig.dpi": 110, "font.size": 9, "axes.grid": True,
    "grid.alpha": 0.3, "axes.spines.top": False, "axes.spines.right": False,
    "legend.fontsize": 8, "legend.frameon": False,
}


class Series(NamedTuple):
    """One curve of :func:`plot_accuracy_vs_time` (the fields it reads from a method run).

    Attributes
    ----------
    label : str
        Legend text.
    seconds : sequence of float
        Wall time at each point.
    curve : dict str -> sequence of float
        Metric values at each point (same length as ``seconds``).
    """

    label: str
    seconds: Sequence[float]
    curve: Mapping[str, Sequence[float]]


@contextmanager
def chart_style():
    """Context manager: matplotlib on the Agg backend with :data:`STYLE`; yields ``pyplot``."""
    import matplotlib  # kept local: matplotlib, loaded only when used (start-up)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # kept local: matplotlib, loaded only when used (start-up)

    with plt.rc_context(STYLE):
        yield plt


def plot_accuracy_vs_time(methods: Sequence[Any], panels: Sequence[Mapping[str, Any]],
                          path: str | Path, *, title: str = "",
                          time_limit: float | None = None,
                          reference_points: Iterable[Mapping[str, Any]] = (),
                          xlabel: str = "solver wall time (s, log)") -> Path:
    """One figure, one panel per metric, one curve per method, accuracy against seconds.

    Parameters
    ----------
    methods : sequence of Series (or any object with ``label``, ``seconds`` and ``curve``)
        The curves, e.g. :class:`Series` or the benchmark harness's ``MethodRun``.
    panels : sequence of dict
        Per panel: ``metric`` (key in ``curve``), ``label`` (y-axis text), ``logy`` (bool),
        optional ``target`` (a horizontal line: the accuracy to reach) and ``target_label``.
        Non-finite values (and values <= 0 on a log axis) are left out of the curves.
    path : str or Path
        PNG to write (its folder is created).
    title : str
        Figure title.
    time_limit : float, optional
        A vertical dashed line (e.g. the time budget of an acceptance criterion).
    reference_points : iterable of dict
        Single measurements to mark with a star: ``seconds``, ``label`` and one value per panel
        metric.
    xlabel : str
        Text of the (log) time axis.

    Returns
    -------
    Path
        ``path``, replaced only once the figure is complete (a failed write raises OSError and
        leaves it unchanged).

    Raises
    ------
    ValueError
        If ``panels`` is empty or a panel has no ``metric``.
    """
    panels = list(panels)
    if not panels:
        raise ValueError("panels: expected at least one panel, got none")
    for i, p in enumerate(panels):
        if "metric" not in p:
            raise ValueError(f"panels[{i}]: expected a 'metric' key, got {sorted(p)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    refs = list(reference_points)
    with chart_style() as plt:
        fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.0), squeeze=False)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for ax, panel in zip(axes[0], panels):
            key = panel["metric"]
            logy = bool(panel.get("logy"))
            positive = False
            for i, m in enumerate(methods):
                if key not in m.curve or not len(m.seconds):
                    continue
                t = np.maximum(np.asarray(m.seconds, dtype=np.float64), 1e-3)
                y = np.asarray(m.curve[key], dtype=np.float64)
                y = np.where(np.isfinite(y) & ((y > 0) if logy else True), y, np.nan)
                positive |= bool(np.any(y > 0))
                ax.plot(t, y, marker="o", ms=2.5, lw=1.4,
                        color=colors[i % len(colors)], label=m.label)
            for r in refs:
                if key in r:
                    ax.plot([r["seconds"]], [r[key]], marker="*", ms=12, color="black",
                            ls="none", label=r.get("label"))
            if panel.get("target") is not None:
                ax.axhline(panel["target"], color="black", lw=0.8, ls=":",
                           label=panel.get("target_label"))
            if time_limit is not None:
                ax.axvline(time_limit, color="crimson", lw=0.8, ls="--",
                           label=f"{time_limit:g} s")
            ax.set_xscale("log")
            _plain_log_labels(ax.xaxis, ax.get_xlim())
            if logy and positive:  # (a log axis without positive data would warn)
                ax.set_yscale("log")
                _plain_log_labels(ax.yaxis, ax.get_ylim())
            ax.set_xlabel(xlabel)
            ax.set_ylabel(panel.get("label", key))
        seen: dict[str, Any] = {}
        for ax in axes[0]:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                if lab and lab not in seen:
                    seen[lab] = h
        ncol = _legend_columns(list(seen), 5.2 * len(panels))
        n_rows = -(-max(len(seen), 1) // ncol)
        if seen:
            fig.legend(list(seen.values()), list(seen.keys()), loc="lower center",
                       ncol=ncol, bbox_to_anchor=(0.5, -0.01))
        if title:
            fig.suptitle(title)
        height = 3.4 + 0.2 * n_rows  # room for the legend below the panels
        fig.set_size_inches(5.2 * len(panels), height)
        fig.tight_layout(rect=(0, (0.12 + 0.2 * n_rows) / height, 1, 1))
        atomic_write(path, fig.savefig)
        plt.close(fig)
    return path


def _plain_log_labels(axis, limits) -> None:
    """Log-axis tick labels as plain numbers (0.05, 2, 10); minor labels at 2x and 5x only when
    the axis spans two decades or less (so they never crowd)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # kept local: start-up

    fmt = FuncFormatter(lambda v, _pos: f"{v:g}")
    axis.set_major_formatter(fmt)
    lo, hi = (float(v) for v in limits)
    few = lo > 0 and hi > lo and np.log10(hi / lo) <= 2.0
    axis.set_minor_locator(LogLocator(subs=(2.0, 5.0) if few else (2.0, 3.0, 4.0, 5.0, 6.0,
                                                                     7.0, 8.0, 9.0)))
    axis.set_minor_formatter(fmt if few else NullFormatter())


def _legend_columns(labels: Sequence[str], width_inches: float) -> int:
    """Legend columns that fit the figure width (about 0.075 inch per character at 8 pt)."""
    if not labels:
        return 1
    per_entry = 0.075 * max(len(s) for s in labels) + 0.5  # text plus the line sample
    return int(max(1, min(4, len(labels), width_inches // per_entry)))


def plot_model_sizes(sizes: Mapping[str, float], path: str | Path, *, title: str = "",
                     xlabel: str = "free parameters (log)",
                     highlight: Iterable[str] = ()) -> Path:
    """Parameter counts as horizontal bars on a log axis, with the count printed on each bar.

    Parameters
    ----------
    sizes : dict str -> number
        Label -> count (> 0), drawn top to bottom in the given order.
    path : str or Path
        PNG to write.
    title, xlabel : str
        Figure title and axis text.
    highlight : iterable of str
        Labels drawn in the second colour of the cycle (e.g. the PyTorch3D recipes).

    Returns
    -------
    Path
        ``path``, the chart written.

    Raises
    ------
    ValueError
        If ``sizes`` is empty or a count is not a positive finite number.
    """
    items = [(str(k), float(v)) for k, v in dict(sizes).items()]
    if not items:
        raise ValueError("sizes: expected at least one entry, got none")
    for k, v in items:
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"sizes[{k!r}]: expected a positive count, got {v!r}")
    hl = set(highlight)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with chart_style() as plt:
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        fig, ax = plt.subplots(figsize=(6.4, 0.45 * len(items) + 1.1))
        y = np.arange(len(items))[::-1]
        vals = [v for _, v in items]
        ax.barh(y, vals, color=[colors[1] if k in hl else colors[0] for k, _ in items])
        ax.set_yticks(y, [k for k, _ in items])
        ax.set_xscale("log")
        ax.set_xlim(min(vals) / 3, max(vals) * 8)
        for yi, v in zip(y, vals):
            ax.text(v * 1.1, yi, f"{v:,.0f}", va="center", fontsize=8)
        ax.set_xlabel(xlabel)
        ax.grid(axis="y", visible=False)
        if title:
            ax.set_title(title)
        fig.tight_layout()
        atomic_write(path, fig.savefig)
        plt.close(fig)
    return path


# ------------------------------------------------------------------------------------ images
def to_uint8(image) -> np.ndarray:
    """Float image in [0, 1] (values outside are clipped, NaN becomes 0) -> uint8.

    Parameters
    ----------
    image : (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) float
        The image (RGBA keeps its alpha).

    Returns
    -------
    (H, W) or (H, W, C) uint8
        ``round(255 * clip(image, 0, 1))``; a single channel is squeezed.

    Examples
    --------
    >>> to_uint8(np.array([[0.0, 0.5, 1.2]])).tolist()
    [[0, 128, 255]]
    """
    a = np.asarray(image, dtype=np.float64)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)):
        raise ValueError(f"image: expected shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), "
                         f"got {a.shape}")
    a = np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save_png(image, path: str | Path) -> Path:
    """Write a float image in [0, 1] (see :func:`to_uint8`) or a uint8 image as a PNG."""
    from PIL import Image  # kept local: Pillow, loaded only when used (start-up)

    a = np.asarray(image)
    u8 = a if a.dtype == np.uint8 else to_uint8(a)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: Image.fromarray(u8).save(tmp, optimize=True))
    return path


def _font(size: int):
    from PIL import ImageFont  # kept local: Pillow, loaded only when used (start-up)

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: bitmap font only
        return ImageFont.load_default()


def _as_rgb(img) -> np.ndarray:
    a = as_array(img, "image", dtype=np.float64, finite=False)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise ValueError(f"images: expected (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) images, "
                         f"got {a.shape}")
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return a[..., :3]


def image_panel(rows: Sequence[Sequence[Any]], path: str | Path, *,
                col_labels: Sequence[str] | None = None,
                row_labels: Sequence[str] | None = None, tile: int | None = None,
                pad: int = 4, font_size: int = 13, background=(255, 255, 255)) -> Path:
    """A labelled grid of images (e.g. targets in the first column, results next to them).

    Parameters
    ----------
    rows : sequence of sequence of (H, W[, C]) float in [0, 1] or None
        ``rows[i][j]`` is the image in row ``i``, column ``j`` (None leaves the cell empty).
        Images may have different sizes; each is scaled (nearest neighbour for upscaling,
        Lanczos for downscaling) to ``tile`` pixels on its longer side.
    path : str or Path
        PNG to write.
    col_labels : sequence of str, optional
        Text above each column.
    row_labels : sequence of str, optional
        Text left of each row.
    tile : int, optional
        Tile size in pixels (default: the largest image side or the widest column label,
        at least 128 and at most 256).
    pad : int
        Pixels between tiles.
    font_size : int
        Label text size.
    background : (3,) int
        Colour of the padding and of empty cells.

    Returns
    -------
    Path
        ``path``, the labelled grid written.

    Raises
    ------
    ValueError
        For an empty grid, label lists of the wrong length or a bad image shape.
    """
    from PIL import Image, ImageDraw  # kept local: Pillow, loaded only when used (start-up)

    rows = [list(r) for r in rows]
    n_cols = max((len(r) for r in rows), default=0)
    if not rows or n_cols == 0:
        raise ValueError("rows: expected at least one image, got an empty grid")
    if col_labels is not None and len(col_labels) != n_cols:
        raise ValueError(f"col_labels: expected {n_cols} labels, got {len(col_labels)}")
    if row_labels is not None and len(row_labels) != len(rows):
        raise ValueError(f"row_labels: expected {len(rows)} labels, got {len(row_labels)}")
    imgs = [[None if im is None else _as_rgb(im) for im in r] for r in rows]
    if all(im is None for r in imgs for im in r):
        raise ValueError("rows: expected at least one image, got only empty cells")
    font = _font(font_size)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))

    def text_size(s: str) -> tuple[int, int]:
        box = probe.multiline_textbbox((0, 0), s, font=font)
        return box[2] - box[0], box[3] - box[1]

    if tile is None:
        largest = max(max(im.shape[:2]) for r in imgs for im in r if im is not None)
        widest = max((text_size(s)[0] for s in col_labels or ()), default=0)
        tile = min(256, max(largest, 128, widest))
    tile = int(tile)
    if tile < 1:
        raise ValueError(f"tile: expected a positive size, got {tile}")

    head = 0
    if col_labels is not None:
        head = max(text_size(s)[1] for s in col_labels) + 2 * pad
    left = 0
    if row_labels is not None:
        left = max(text_size(s)[0] for s in row_labels) + 2 * pad
    W = left + n_cols * tile + (n_cols + 1) * pad
    H = head + len(rows) * tile + (len(rows) + 1) * pad
    canvas = Image.new("RGB", (W, H), tuple(int(c) for c in background))
    draw = ImageDraw.Draw(canvas)
    for j in range(n_cols):  # columns
        x0 = left + pad + j * (tile + pad)
        if col_labels is not None:
            tw, _ = text_size(col_labels[j])
            draw.multiline_text((x0 + max(0, (tile - tw) // 2), pad), col_labels[j],
                                fill=(0, 0, 0), font=font, align="center")
    for i, r in enumerate(imgs):  # rows
        y0 = head + pad + i * (tile + pad)
        if row_labels is not None:
            _, th = text_size(row_labels[i])
            draw.multiline_text((pad, y0 + max(0, (tile - th) // 2)), row_labels[i],
                                fill=(0, 0, 0), font=font)
        for j, im in enumerate(r):  # cells
            if im is None:
                continue
            h, w = im.shape[:2]
            s = tile / max(h, w)
            size = (max(1, round(w * s)), max(1, round(h * s)))
            pil = Image.fromarray(to_uint8(im))
            if size != (w, h):
                pil = pil.resize(size, Image.NEAREST if s > 1 else Image.LANCZOS)
            x0 = left + pad + j * (tile + pad)
            canvas.paste(pil, (x0 + (tile - size[0]) // 2, y0 + (tile - size[1]) // 2))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: canvas.save(tmp, optimize=True))
    return path


class Table:
    """Rows of results shown as a table: an HTML table in a notebook (``_repr_html_``), aligned
    text in a terminal (``str``). Numbers are formatted with ``formats[column]`` (a format
    spec such as ``".3g"``; default: ``".4g"`` for floats), anything else with ``str``.

    Parameters
    ----------
    rows : sequence of sequence
        One sequence of values per row, in the order of ``columns``.
    columns : sequence of str
        Column titles.
    formats : dict of str to str, optional
        Format spec per column title.
    title : str, optional
        A caption above the table.

    Examples
    --------
    >>> print(Table([("sgd", 2562, 0.0512)], ["fit", "verts", "chamfer-L2"],
    ...             {"chamfer-L2": ".2e"}))
    fit  verts  chamfer-L2
    sgd   2562    5.12e-02
    """

    def __init__(self, rows: Sequence[Sequence[Any]], columns: Sequence[str],
                 formats: Mapping[str, str] | None = None, title: str | None = None):
        self.columns = [str(c) for c in columns]
        self.rows = [list(r) for r in rows]
        bad = [i for i, r in enumerate(self.rows) if len(r) != len(self.columns)]
        if bad:
            raise ValueError(f"rows: row {bad[0]} has {len(self.rows[bad[0]])} values, expected "
                             f"{len(self.columns)} (one per column)")
        self.formats = dict(formats or {})
        self.title = title

    def _cell(self, column: str, value) -> str:
        spec = self.formats.get(column)
        if isinstance(value, (bool, np.bool_)) or value is None:
            return str(value)
        if isinstance(value, (int, np.integer)) and spec is None:
            return str(int(value))
        if isinstance(value, (float, np.floating, int, np.integer)):
            return format(float(value), spec or ".4g")
        return str(value)

    def _cells(self) -> list[list[str]]:
        return [[self._cell(c, v) for c, v in zip(self.columns, r)] for r in self.rows]

    def __str__(self) -> str:
        cells = self._cells()
        numeric = [all(isinstance(r[j], (int, float, np.integer, np.floating))
                       and not isinstance(r[j], bool) for r in self.rows) and bool(self.rows)
                   for j in range(len(self.columns))]
        widths = [max([len(c)] + [len(r[j]) for r in cells]) for j, c in enumerate(self.columns)]

        def line(values):
            return "  ".join(v.rjust(w) if num else v.ljust(w)
                             for v, w, num in zip(values, widths, numeric)).rstrip()

        out = ([self.title] if self.title else []) + [line(self.columns)]
        return "\n".join(out + [line(r) for r in cells])

    def __repr__(self) -> str:
        return str(self)

    def _repr_html_(self) -> str:
        import html

        e = html.escape
        head = "".join(f"<th>{e(c)}</th>" for c in self.columns)
        body = "".join("<tr>" + "".join(f"<td>{e(v)}</td>" for v in r) + "</tr>"
                       for r in self._cells())
        cap = f"<caption>{e(self.title)}</caption>" if self.title else ""
        return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
