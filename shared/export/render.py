"""Draw a map snapshot to SVG or PNG with matplotlib (Agg canvas, no pyplot, no global state changed).

Layers, bottom to top: optional ground-truth walls (light grey, wide), the trajectory (thin green line),
the map segments (thick blue), cluster centroids (small orange dots), the final pose (vermilion arrow).
Colours are from the Okabe-Ito colour-blind-safe palette and read on white. Equal aspect, a labelled scale
bar of a round length (1-2-5 x 10^k m) and a legend with counts. matplotlib is imported on first call so that
``import shared.export`` stays cheap on the robot.
"""

from __future__ import annotations

import io
import logging
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.export.atomic import atomic_write_bytes
from shared.export.errors import UnsupportedFormatError
from shared.export.svg_meta import SVG_WALLS_ID, embed_map_metadata
from shared.export.validate import CheckedSnapshot, check_rows, check_snapshot
from shared.pipeline.snapshot import MapSnapshot
from shared.types import FloatArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.collections import LineCollection

__all__ = ["RENDER_FORMATS", "render_map", "scale_bar_length_m"]

_log = logging.getLogger(__name__)

RENDER_FORMATS = (".png", ".svg")
"""File suffixes :func:`render_map` can write (case-insensitive)."""

# Okabe & Ito (2008) palette
_WALL = "#0072B2"  # blue
_CENTROID = "#E69F00"  # orange
_TRAJECTORY = "#009E73"  # bluish green
_POSE = "#D55E00"  # vermilion
_TRUTH = "#C8C8C8"  # light grey
_FIG_INCHES = 8.0  # the larger side; dpi = size_px / _FIG_INCHES keeps text proportional to the image
_MIN_SIZE_PX, _MAX_SIZE_PX = 200, 20000


def scale_bar_length_m(span_m: float, *, fraction: float = 0.2) -> float:
    """The largest round length (1, 2 or 5 x 10^k m) not above ``fraction`` of ``span_m``. O(1).

    E.g. a 12 m wide map gets a 2 m bar, a 60 m one 10 m; a non-positive span gives 1 m.
    """
    target = span_m * fraction
    if not math.isfinite(target) or target <= 0.0:
        return 1.0
    decade = 10.0 ** math.floor(math.log10(target))
    best = decade
    for mult in (2.0, 5.0, 10.0):
        if mult * decade <= target * (1.0 + 1e-9):
            best = mult * decade
    return best


def _format_length(length_m: float) -> str:
    if length_m < 1.0:
        return f"{round(length_m * 100.0):d} cm"
    return f"{length_m:g} m"


def _extent(
    checked: CheckedSnapshot, walls: FloatArray, show_pose: bool
) -> tuple[float, float, float, float]:
    parts = [
        checked.segments.reshape(-1, 2),
        walls.reshape(-1, 2),
        checked.centroids,
        checked.trajectory[:, 1:3],
    ]
    if show_pose:
        parts.append(np.array([checked.pose_xy_theta[:2]]))
    pts = np.vstack(parts)
    if pts.shape[0] == 0:
        return -1.0, 1.0, -1.0, 1.0
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    pad = max(0.05 * span, 0.5)
    bar_strip = 0.08 * max(span, 2.0)  # empty band at the bottom so the scale bar hides no data
    return float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad - bar_strip), float(hi[1] + pad)


def _figure_inches(ratio: float, *, has_title: bool) -> tuple[float, float]:
    """Figure size whose axes box has about the map's height/width ``ratio``; larger side _FIG_INCHES."""
    ratio = min(max(ratio, 0.15), 4.0)
    side_margin = 0.9  # y tick labels and label
    overhead = 1.4 + (0.35 if has_title else 0.0)  # x labels, legend rows, title
    if ratio <= 1.0:
        fig_w = _FIG_INCHES
        fig_h = (fig_w - side_margin) * ratio + overhead
    else:
        fig_h = _FIG_INCHES
        fig_w = max((fig_h - overhead) / ratio + side_margin, 0.6 * _FIG_INCHES)  # room for the legend
    scale = _FIG_INCHES / max(fig_w, fig_h)
    return fig_w * scale, fig_h * scale


def _path_length_m(traj: FloatArray) -> float:
    if traj.shape[0] < 2:
        return 0.0
    return float(np.hypot(*np.diff(traj[:, 1:3], axis=0).T).sum())


def _lines(segments: FloatArray, color: str, width: float, z: int) -> LineCollection:
    from matplotlib.collections import LineCollection

    pieces = list(segments.reshape(-1, 2, 2))
    return LineCollection(pieces, colors=color, linewidths=width, capstyle="round", zorder=z)


def _draw(ax: Axes, checked: CheckedSnapshot, walls: FloatArray, show_pose: bool, span: float) -> list[Any]:
    from matplotlib.lines import Line2D

    handles: list[Any] = []
    if walls.shape[0]:
        ax.add_collection(_lines(walls, _TRUTH, 6.0, 1))
        handles.append(Line2D([], [], color=_TRUTH, lw=6.0, label=f"true walls ({walls.shape[0]})"))
    traj = checked.trajectory
    if traj.shape[0]:
        ax.plot(traj[:, 1], traj[:, 2], color=_TRAJECTORY, lw=1.2, zorder=2)
        label = f"trajectory ({traj.shape[0]} poses, {_path_length_m(traj):.1f} m)"
        handles.append(Line2D([], [], color=_TRAJECTORY, lw=1.5, label=label))
    segs = checked.segments
    if segs.shape[0]:
        walls_drawn = _lines(segs, _WALL, 2.6, 3)
        walls_drawn.set_gid(SVG_WALLS_ID)  # <g id="walls"> in SVG, one path per segment in order
        ax.add_collection(walls_drawn)
        handles.append(Line2D([], [], color=_WALL, lw=2.6, label=f"map segments ({segs.shape[0]})"))
    cents = checked.centroids
    if cents.shape[0]:
        dot_pt2 = float(np.clip(7.0 * math.sqrt(500.0 / cents.shape[0]), 1.5, 7.0))  # smaller when crowded
        ax.scatter(cents[:, 0], cents[:, 1], s=dot_pt2, c=_CENTROID, linewidths=0.0, zorder=4)
        handles.append(
            Line2D([], [], color=_CENTROID, marker="o", ms=4.0, ls="", label=f"centroids ({cents.shape[0]})")
        )
    if show_pose:
        x, y, theta = checked.pose_xy_theta
        length = 0.06 * span
        tip = (x + length * math.cos(theta), y + length * math.sin(theta))
        ax.annotate(
            "",
            xy=tip,
            xytext=(x, y),
            arrowprops={"arrowstyle": "-|>", "color": _POSE, "lw": 2.2, "mutation_scale": 18},
            zorder=5,
        )
        ax.plot([x], [y], marker="o", ms=5.0, color=_POSE, zorder=5)
        handles.append(
            Line2D(
                [],
                [],
                color=_POSE,
                marker=">",
                ms=7.0,
                lw=2.2,
                label=f"final pose ({math.degrees(theta):.0f}°)",
            )
        )
    return handles


def _scale_bar(ax: Axes, width_m: float, height_m: float) -> None:
    from matplotlib.offsetbox import AnchoredOffsetbox, AuxTransformBox, TextArea, VPacker
    from matplotlib.patches import Rectangle

    length = scale_bar_length_m(width_m)
    bar = AuxTransformBox(ax.transData)
    bar.add_artist(
        Rectangle((0.0, 0.0), length, 0.007 * max(width_m, height_m), facecolor="black", edgecolor="none")
    )
    label = TextArea(_format_length(length), textprops={"fontsize": 9, "color": "black"})
    packed = VPacker(children=[bar, label], align="center", pad=0, sep=3)
    anchored = AnchoredOffsetbox(loc="lower left", child=packed, pad=0.4, borderpad=0.8, frameon=True)
    anchored.patch.set_facecolor("white")
    anchored.patch.set_alpha(0.85)
    anchored.patch.set_edgecolor("none")
    anchored.set_zorder(6)
    ax.add_artist(anchored)


def render_map(
    snapshot: MapSnapshot,
    path: str | os.PathLike[str],
    *,
    walls: ArrayLike | None = None,
    title: str | None = None,
    size_px: int = 1200,
) -> None:
    """Draw ``snapshot`` (and optional ground-truth ``walls`` ``(W, 4)`` metres) to ``path``.

    The format comes from the suffix: ``.png`` (raster; the larger image side is ``size_px`` pixels) or
    ``.svg`` (vector, same layout). The final pose is drawn once the trajectory has a row (before the first
    step the pose is only the default origin). An empty map gives an empty framed plot. Written atomically.
    O(L + C + T) plus matplotlib's drawing (about 0.1-0.5 s for thousands of segments).

    Raises :class:`UnsupportedFormatError` for another suffix, :class:`InvalidInputError` for bad arrays or
    ``size_px`` outside 200..20000, :class:`~shared.export.errors.ExportIOError` when writing fails.
    """
    target = Path(path)
    fmt = target.suffix.lower()
    if fmt not in RENDER_FORMATS:
        raise UnsupportedFormatError(
            f"{target}: suffix {target.suffix!r}: expected one of {', '.join(RENDER_FORMATS)}"
        )
    if isinstance(size_px, bool) or not isinstance(size_px, int | np.integer):
        raise InvalidInputError(f"size_px = {size_px!r}: expected an integer number of pixels")
    if not _MIN_SIZE_PX <= size_px <= _MAX_SIZE_PX:
        raise InvalidInputError(f"size_px = {size_px}: expected {_MIN_SIZE_PX}..{_MAX_SIZE_PX} pixels")
    checked = check_snapshot(snapshot)
    true_walls = check_rows([] if walls is None else walls, 4, "walls", "[x0, y0, x1, y1] metres")
    show_pose = checked.trajectory.shape[0] > 0

    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    x0, x1, y0, y1 = _extent(checked, true_walls, show_pose)
    width_m, height_m = x1 - x0, y1 - y0
    fig_w, fig_h = _figure_inches(height_m / width_m, has_title=bool(title))
    fig = Figure(figsize=(fig_w, fig_h), dpi=size_px / _FIG_INCHES, layout="constrained", facecolor="white")
    FigureCanvasAgg(fig)  # attaches itself to fig: an explicit Agg canvas, pyplot never involved
    ax = fig.add_subplot()
    ax.set_facecolor("white")
    handles = _draw(ax, checked, true_walls, show_pose, max(width_m, height_m))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.tick_params(labelsize=8, colors="#444444")
    for spine in ax.spines.values():
        spine.set_color("#888888")
    _scale_bar(ax, width_m, height_m)
    if title:
        ax.set_title(title)
    if not handles:
        ax.text(0.5, 0.5, "empty map", transform=ax.transAxes, ha="center", va="center", color="#888888")
    else:
        fig.legend(
            handles=handles, loc="outside lower center", ncols=min(len(handles), 3), frameon=False, fontsize=9
        )
    buffer = io.BytesIO()
    save_kwargs: dict[str, Any] = {"format": fmt[1:], "facecolor": "white"}
    save_kwargs["metadata"] = {"Date": None} if fmt == ".svg" else {"Software": "linemap"}
    # a fixed hash salt makes SVG element ids, hence the file, reproducible; rc_context restores it after
    with matplotlib.rc_context({"svg.hashsalt": "linemap"}):
        fig.savefig(buffer, **save_kwargs)
    data = buffer.getvalue()
    if fmt == ".svg":  # the walls in metres, for reading back (shared.export.svg_meta); not drawn
        data = embed_map_metadata(data, checked.segments, checked.segment_ids)
    atomic_write_bytes(target, data)
    _log.debug("rendered %s: %d segments, %d bytes", target, checked.segments.shape[0], buffer.tell())
