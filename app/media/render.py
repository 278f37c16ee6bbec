"""Pictures and movies of scene frames for slides: ``granlab render`` and the lab's recordings.

A picture shows the disks (filled circles, true size) in the colours of one colour field, a
spoke per disk from its centre to its rim at its rotation angle θ, the force network (segments
whose width grows with |F| in the classes of :func:`granlab.app.media.drawing.force_classes`, coloured by
contact kind), the walls or the periodic cell, and a legend with a caption. Colours are the lab
scene's (:mod:`granlab.app.media.drawing`).

Everything is drawn on a :class:`matplotlib.figure.Figure` of its own with the Agg canvas (no
pyplot, no global state), so pictures may be rendered from a background thread. Errors name
the parameter, its value and what is allowed (:class:`granlab.engine.errors.ParameterError`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import EllipseCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, PathPatch, Rectangle
from matplotlib.path import Path as StrokePath

from granlab.engine.errors import OutputError, ParameterError
from granlab.engine.frames import FrameData, SceneFrame, build_frame, cell_outline
from granlab.engine.io import h5md
from granlab.engine.io.frame_selection import reporting, select_frames
from granlab.engine.io.outputs import check_output, staged

from .drawing import (CELL_COLOR, COLOR_FIELDS, CONTACT_KINDS, COORDINATION_COLORS, FORCE_CLASSES, LABEL_SIZE,
                      PRESSURE_LUT, ROTATION_LUT, SLIDING_DISK_COLORS, SPOKE_COLOR, WALL_COLOR, WATCHED_COLORS,
                      WATCHED_THICKNESS, disk_colors, force_class_thickness, force_classes, frame_bounds, frame_caption)

SUFFIXES = (".png", ".gif", ".mp4")
"""What :func:`write_movie` writes: one picture (or one per frame), an animated GIF, an H.264 movie."""

MIN_SIZE = (480, 270)
MAX_SIZE = (7680, 4320)
"""Smallest and largest picture, (width, height) in pixels: a smaller one has no room for a
legend of MIN_EM beside a packing."""

MAX_FPS = 50.0
"""GIF delays are whole hundredths of a second and browsers slow down shorter ones."""

DPI = 100
POINTS_PER_PIXEL = 72.0 / DPI
"""Matplotlib sizes fonts and lines in points; everything here is sized in pixels."""

SPOKE_WIDTH = 0.12
WALL_WIDTH = 0.25
CELL_WIDTH = 0.12
DISK_EDGE_WIDTH = 0.04
"""Line widths as fractions of the mean radius (drawn at least MIN_LINE_PX wide)."""

FORCE_BORDER = 0.12
"""A force line has a white border this fraction of its width on each side: compressive red on
a red disk (θ near 0) would otherwise not show."""

MIN_LINE_PX = 1.0
DISK_EDGE_COLOR = (70, 70, 70)
TEXT_COLOR = "#1a1a1a"
MARGIN = 0.025
"""Blank border around the packing, as a fraction of its larger side."""

EM_AT_720P = 24.0
MIN_EM = 12.0
"""Legend font size in pixels: 24 px in a 1280x720 picture (a thirtieth of its height, readable
from the back of a lecture room), scaled with the picture, never below 12 px."""

CHAR_WIDTH = 0.55
BOLD_WIDTH = 1.15
"""Width of an average character of the legend font, in em, and how much wider bold is (to size
the legend before drawing; DejaVu Sans digits are 0.64 em, lower-case letters about 0.5)."""

CAPTION_CHARS = 30
"""The legend is sized for caption lines of at least this many characters, so that the captions
of a movie (``t = 1234.5, step 1234567`` is 24, ``cycle 123 · q = 0.312, falling`` 30) do not
move the packing from frame to frame."""

WATCHED_ROWS = 8
"""The legend names at most this many watched contacts (one per colour), then says how many more."""

LEGEND_LINE = 0.3
"""Width of the line samples of the legend, in em (the cell's: half of it)."""

LEGEND_PAD = 0.8
BLOCK_GAP = 0.7
"""Padding around the legend and space between its blocks, in em."""


def _rgb(color) -> tuple[float, float, float]:
    return tuple(c / 255.0 for c in color)


def _points(pixels):
    return np.asarray(pixels) * POINTS_PER_PIXEL


def check_color_field(color_field: str, name: str = "color_field") -> str:
    if color_field not in COLOR_FIELDS:
        raise ParameterError(name, color_field, "one of " + ", ".join(COLOR_FIELDS))
    return color_field


def check_out(out: Path, name: str = "out") -> str:
    """The lower-case suffix of ``out``, a file to be written in an existing folder."""
    suffix = out.suffix.lower()
    if suffix not in SUFFIXES:
        raise ParameterError(f"{name} suffix", out.suffix, ", ".join(SUFFIXES) + " (a picture, an animated GIF, "
                                                                                "an H.264 movie)")
    if out.is_dir():
        raise ParameterError(name, str(out), "a file name; this is a folder")
    folder = out.parent
    if not folder.is_dir():
        raise ParameterError(name, str(out), f"a file in an existing folder; {str(folder)!r} does not exist")
    return suffix


def check_size(size, name: str = "size", suffix: str | None = None) -> tuple[int, int]:
    """(width, height) in pixels from a pair or a ``"WIDTHxHEIGHT"`` text. A ``.mp4`` needs both
    even (H.264 in yuv420p halves the colour resolution); odd sizes are refused, not rounded, so
    a movie always has the size asked for."""
    allowed = (f"WIDTHxHEIGHT in pixels, width {MIN_SIZE[0]}..{MAX_SIZE[0]} and height {MIN_SIZE[1]}..{MAX_SIZE[1]}, "
               "e.g. 1280x720")
    if isinstance(size, str):
        match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", size)
        if match is None:
            raise ParameterError(name, size, allowed)
        pair = (int(match[1]), int(match[2]))
    else:
        try:
            pair = tuple(int(v) for v in size)
        except (TypeError, ValueError):
            raise ParameterError(name, size, allowed) from None
    if len(pair) != 2 or not all(lo <= v <= hi for v, lo, hi in zip(pair, MIN_SIZE, MAX_SIZE)):
        raise ParameterError(name, size, allowed)
    if suffix == ".mp4" and (pair[0] % 2 or pair[1] % 2):
        raise ParameterError(name, size, "an even width and height for .mp4 (H.264 in yuv420p), e.g. 1280x720")
    return pair


def check_fps(fps, name: str = "fps") -> float:
    allowed = f"frames per second, a number > 0 and <= {MAX_FPS:g}"
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise ParameterError(name, fps, allowed) from None
    if not 0.0 < value <= MAX_FPS:
        raise ParameterError(name, fps, allowed)
    return value


def _walls_cut_at_corners(frame: SceneFrame) -> SceneFrame:
    """The frame with each wall drawn where it bounds the disks: its line, within the frame's
    bounds, on the disks' side of every other wall (the side holding the disks' centroid). A
    wall is a whole line to the disks, so this is the edge of their domain: a box is drawn as a
    closed box, not as four lines crossing or stopping short of each other at the corners."""
    walls = frame.walls
    if len(walls) < 2 or len(frame.radii) == 0:
        return frame
    xmin, xmax, ymin, ymax = frame_bounds(frame)
    starts, along = walls[:, 0], walls[:, 1] - walls[:, 0]
    inward = np.column_stack([-along[:, 1], along[:, 0]])
    inward *= np.sign(np.einsum("ij,ij->i", frame.positions.mean(axis=0) - starts, inward))[:, None]
    # half-planes normal . x >= offset: the four sides of the bounds, then the walls
    box = [(np.array([1.0, 0.0]), xmin), (np.array([-1.0, 0.0]), -xmax), (np.array([0.0, 1.0]), ymin),
           (np.array([0.0, -1.0]), -ymax)]
    cut = walls.copy()
    for k in range(len(walls)):
        lo, hi = -np.inf, np.inf  # start_k + u along_k lies in every half-plane for lo <= u <= hi
        others = [(inward[j], inward[j] @ starts[j]) for j in range(len(walls)) if j != k]
        for normal, offset in box + others:
            rate = normal @ along[k]
            if abs(rate) <= 1e-12 * np.linalg.norm(normal) * np.linalg.norm(along[k]):
                continue
            u = (offset - normal @ starts[k]) / rate
            lo, hi = (max(lo, u), hi) if rate > 0.0 else (lo, min(hi, u))
        if lo < hi:
            cut[k] = [starts[k] + lo * along[k], starts[k] + hi * along[k]]
    return dataclasses.replace(frame, walls=cut)


def union_bounds(frames: Iterable[SceneFrame]) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) covering every frame (:func:`granlab.app.media.drawing.frame_bounds`, walls
    cut at the corners of the box they form)."""
    boxes = np.array([frame_bounds(_walls_cut_at_corners(frame)) for frame in frames]).reshape(-1, 4)
    if len(boxes) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    return (float(boxes[:, 0].min()), float(boxes[:, 1].max()), float(boxes[:, 2].min()), float(boxes[:, 3].max()))


# The legend: blocks of rows, each row drawn at a top-left corner in pixels (y downwards) and
# sized in em, so that the layout can be planned before anything is drawn.

@dataclass(frozen=True)
class _Row:
    height: float  # em
    width: float   # em
    draw: Callable[[Axes, float, float, float], None]  # (axes in pixels, x, y of the top, em in pixels)


def _text_row(text: str, size: float = 1.0, bold: bool = False, chars: int = 0) -> _Row:
    """A line of text ``size`` em high, as wide as ``chars`` characters if it is shorter."""
    def draw(ax, x, y, em):
        ax.text(x, y + 0.7 * size * em, text, fontsize=size * em * POINTS_PER_PIXEL, va="center", ha="left",
                color=TEXT_COLOR, fontweight="bold" if bold else "normal")
    return _Row(1.4 * size, CHAR_WIDTH * size * max(len(text), chars) * (BOLD_WIDTH if bold else 1.0), draw)


def _label(ax, x, y, em, text: str) -> None:
    ax.text(x, y, text, fontsize=em * POINTS_PER_PIXEL, va="center", ha="left", color=TEXT_COLOR)


def _swatch_row(color, text: str) -> _Row:
    def draw(ax, x, y, em):
        ax.add_patch(Rectangle((x, y + 0.25 * em), 1.6 * em, 0.9 * em, facecolor=_rgb(color),
                               edgecolor=_rgb(DISK_EDGE_COLOR), linewidth=_points(1.0)))
        _label(ax, x + 2.1 * em, y + 0.7 * em, em, text)
    return _Row(1.4, 2.1 + CHAR_WIDTH * len(text), draw)


def _line_row(color, width: float, text: str, dashed: bool = False) -> _Row:
    """A segment ``width`` em wide and its label."""
    def draw(ax, x, y, em):
        ax.plot([x, x + 1.6 * em], [y + 0.7 * em] * 2, color=_rgb(color), linewidth=_points(width * em),
                linestyle=(0, (3, 2)) if dashed else "-", solid_capstyle="butt")
        _label(ax, x + 2.1 * em, y + 0.7 * em, em, text)
    return _Row(1.4, 2.1 + CHAR_WIDTH * len(text), draw)


def _colorbar_row(table: np.ndarray, ticks: Sequence[tuple[float, str]]) -> _Row:
    """A bar of the colour table ``table`` (T, 3) with labels at fractions of its length."""
    length = 9.0

    def draw(ax, x, y, em):
        ax.imshow(table[None, :, :], extent=(x, x + length * em, y + 1.1 * em, y + 0.1 * em), aspect="auto",
                  interpolation="nearest")
        ax.add_patch(Rectangle((x, y + 0.1 * em), length * em, em, fill=False, edgecolor=_rgb(DISK_EDGE_COLOR),
                               linewidth=_points(1.0)))
        for at, text in ticks:
            ax.text(x + at * length * em, y + 1.75 * em, text, fontsize=em * POINTS_PER_PIXEL, ha="center",
                    va="center", color=TEXT_COLOR)
    return _Row(2.4, length + 1.0, draw)


def _coordination_row() -> _Row:
    """One square per number of contacts 0..6 (6 or more), the number beneath."""
    names = [str(z) for z in range(len(COORDINATION_COLORS) - 1)] + [f"{len(COORDINATION_COLORS) - 1}+"]
    pitch = 1.45

    def draw(ax, x, y, em):
        for k, (color, text) in enumerate(zip(COORDINATION_COLORS, names)):
            left = x + k * pitch * em
            ax.add_patch(Rectangle((left, y + 0.1 * em), 1.2 * em, 1.0 * em, facecolor=_rgb(color),
                                   edgecolor=_rgb(DISK_EDGE_COLOR), linewidth=_points(1.0)))
            ax.text(left + 0.6 * em, y + 1.75 * em, text, fontsize=em * POINTS_PER_PIXEL, ha="center", va="center",
                    color=TEXT_COLOR)
    return _Row(2.4, pitch * len(names), draw)


def _spoke_row() -> _Row:
    text = "spoke: rotation angle θ"

    def draw(ax, x, y, em):
        centre, radius = (x + 0.8 * em, y + 0.7 * em), 0.6 * em
        ax.add_patch(Circle(centre, radius, facecolor="white", edgecolor=_rgb(DISK_EDGE_COLOR),
                            linewidth=_points(1.0)))
        angle = math.radians(40.0)  # y points down in the legend: the spoke leans up and right
        ax.plot([centre[0], centre[0] + radius * math.cos(angle)], [centre[1], centre[1] - radius * math.sin(angle)],
                color=_rgb(SPOKE_COLOR), linewidth=_points(max(MIN_LINE_PX, 0.1 * em)))
        _label(ax, x + 2.1 * em, y + 0.7 * em, em, text)
    return _Row(1.4, 2.1 + CHAR_WIDTH * len(text), draw)


def _width_row() -> _Row:
    """Short segments, one per force class, in widths growing as the classes' do."""
    text = "line width ∝ |F|"

    def draw(ax, x, y, em):
        step = 1.6 * em / FORCE_CLASSES
        for k in range(FORCE_CLASSES):
            ax.plot([x + k * step, x + (k + 0.8) * step], [y + 0.7 * em] * 2, color=_rgb(CONTACT_KINDS[0][1]),
                    linewidth=_points(max(MIN_LINE_PX, (k + 1) / FORCE_CLASSES * 0.6 * em)), solid_capstyle="butt")
        _label(ax, x + 2.1 * em, y + 0.7 * em, em, text)
    return _Row(1.4, 2.1 + CHAR_WIDTH * len(text), draw)


def _color_block(color_field: str) -> list[_Row]:
    if color_field == "rotation":
        rows = [_text_row("disks: rotation θ", bold=True),
                _colorbar_row(ROTATION_LUT, [(0.0, "0"), (0.5, "π"), (1.0, "2π")])]
    elif color_field == "coordination":
        rows = [_text_row("disks: contacts", bold=True), _coordination_row()]
    elif color_field == "pressure":
        rows = [_text_row("disks: pressure p / max p", bold=True),
                _colorbar_row(PRESSURE_LUT, [(0.0, "0"), (0.5, "0.5"), (1.0, "1")])]
    else:
        rows = [_text_row("disks: sliding", bold=True), _swatch_row(SLIDING_DISK_COLORS[0], "no sliding contact"),
                _swatch_row(SLIDING_DISK_COLORS[1], "a sliding contact")]
    return rows + [_spoke_row()]


def _caption_block(caption: str) -> list[_Row]:
    """The caption's lines: the first large and bold (the protocol's phase, or the time), the
    others plain."""
    lines = caption.split("\n")
    return ([_text_row(lines[0], size=1.15, bold=True, chars=CAPTION_CHARS)]
            + [_text_row(line, chars=CAPTION_CHARS) for line in lines[1:]])


def _watched_block(labels: Sequence[str]) -> list[_Row]:
    """The watched contacts in their colours (as in the lab's Coulomb-cone plot)."""
    rows = [_text_row("watched contacts", bold=True)]
    rows += [_line_row(WATCHED_COLORS[k % len(WATCHED_COLORS)], 1.5 * LEGEND_LINE, label)
             for k, label in enumerate(labels[:WATCHED_ROWS])]
    if len(labels) > WATCHED_ROWS:
        rows.append(_text_row(f"and {len(labels) - WATCHED_ROWS} more"))
    return rows


def _legend_blocks(frame: SceneFrame, color_field: str, forces: bool, caption: str,
                   watched_labels: Sequence[str]) -> list[list[_Row]]:
    """Caption, disk colours, contact kinds (with ``forces``), watched contacts, and the walls or
    cell the frame has."""
    blocks = [_caption_block(caption)] if caption else []
    blocks.append(_color_block(color_field))
    if forces:
        blocks.append([_text_row("contact forces", bold=True)]
                      + [_line_row(color, LEGEND_LINE, name) for name, color in CONTACT_KINDS]
                      + [_width_row()])
    if len(watched_labels):
        blocks.append(_watched_block(watched_labels))
    outline = []
    if len(frame.walls):
        outline.append(_line_row(WALL_COLOR, LEGEND_LINE, "wall"))
    if frame.cell is not None:
        outline.append(_line_row(CELL_COLOR, 0.5 * LEGEND_LINE, "periodic cell", dashed=True))
    if outline:
        blocks.append(outline)
    return blocks


@dataclass(frozen=True)
class _Layout:
    """Where things go, in pixels from the bottom-left: the packing's box and its limits, the
    legend's box, the legend's em and whether the legend is a column (else a strip below)."""

    packing: tuple[float, float, float, float]   # x, y, width, height
    limits: tuple[float, float, float, float]    # xmin, xmax, ymin, ymax of the packing (lengths)
    scale: float                                 # pixels per length
    legend: tuple[float, float, float, float]
    em: float
    column: bool


def _block_size(block: list[_Row]) -> tuple[float, float]:
    return max(row.width for row in block), sum(row.height for row in block)


def _layout(size: tuple[int, int], bounds: tuple[float, float, float, float], blocks: list[list[_Row]]) -> _Layout:
    """The packing at equal aspect as large as the picture allows beside (a column at its right)
    or above (a strip) the legend, whichever is larger while the legend's font keeps MIN_EM;
    packing and legend centred together."""
    width, height = size
    xmin, xmax, ymin, ymax = bounds
    margin = MARGIN * max(xmax - xmin, ymax - ymin)
    xmin, xmax, ymin, ymax = xmin - margin, xmax + margin, ymin - margin, ymax + margin
    xspan, yspan = xmax - xmin, ymax - ymin
    em0 = max(MIN_EM, EM_AT_720P * min(width / 1280.0, height / 720.0))
    sizes = [_block_size(block) for block in blocks]
    column_w = max(w for w, _ in sizes) + 2 * LEGEND_PAD
    column_h = sum(h for _, h in sizes) + BLOCK_GAP * (len(sizes) - 1) + 2 * LEGEND_PAD
    strip_w = sum(w for w, _ in sizes) + BLOCK_GAP * (len(sizes) - 1) + 2 * LEGEND_PAD
    strip_h = max(h for _, h in sizes) + 2 * LEGEND_PAD
    em_column = min(em0, height / column_h)
    em_strip = min(em0, width / strip_w)
    scale_column = min((width - column_w * em_column) / xspan, height / yspan)
    scale_strip = min(width / xspan, (height - strip_h * em_strip) / yspan)
    # the larger packing, among the layouts whose legend keeps MIN_EM; else the larger legend
    readable_column, readable_strip = em_column >= MIN_EM, em_strip >= MIN_EM
    if readable_column == readable_strip:
        column = scale_column >= scale_strip if readable_column else em_column >= em_strip
    else:
        column = readable_column
    if column:
        em, scale = em_column, scale_column
        legend_w, legend_h = column_w * em, height
        packing_w, packing_h = xspan * scale, height
        left = 0.5 * (width - packing_w - legend_w)
        packing, legend = (left, 0.0, packing_w, packing_h), (left + packing_w, 0.0, legend_w, legend_h)
    else:
        em, scale = em_strip, scale_strip
        legend_w, legend_h = width, strip_h * em
        packing_w, packing_h = width, yspan * scale
        bottom = 0.5 * (height - packing_h - legend_h)
        packing, legend = (0.0, bottom + legend_h, packing_w, packing_h), (0.0, bottom, legend_w, legend_h)
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    half_w, half_h = 0.5 * packing[2] / scale, 0.5 * packing[3] / scale
    return _Layout(packing, (cx - half_w, cx + half_w, cy - half_h, cy + half_h), scale, legend, em, column)


def _axes(fig: Figure, box: tuple[float, float, float, float], size: tuple[int, int]) -> Axes:
    x, y, w, h = box
    ax = fig.add_axes((x / size[0], y / size[1], w / size[0], h / size[1]))
    ax.set_axis_off()
    return ax


def _add_segments(ax: Axes, segments: np.ndarray, color, width_px: float, zorder: int, capstyle: str = "butt",
                  dashes: tuple[float, float] | None = None) -> None:
    """Segments (S, 2, 2) in data units as one path of S strokes: one colour and width, drawn
    in one pass (a LineCollection builds a path per segment, 0.15 s for 14 000 of them)."""
    if len(segments) == 0:
        return
    codes = np.tile(np.array([StrokePath.MOVETO, StrokePath.LINETO], dtype=StrokePath.code_type), len(segments))
    # add_artist, not add_patch: the axes' limits are set, and add_patch would walk every
    # segment in Python to update them
    ax.add_artist(PathPatch(StrokePath(segments.reshape(-1, 2), codes), fill=False, edgecolor=_rgb(color),
                            linewidth=_points(width_px), capstyle=capstyle, zorder=zorder,
                            linestyle="-" if dashes is None else (0, dashes)))


def _draw_packing(ax: Axes, frame: SceneFrame, color_field: str, forces: bool, scale: float) -> None:
    """Disks, forces, watched contacts, spokes, walls and cell on ``ax`` (its limits set, ``scale``
    pixels per length), lines as wide as the lab scene's (true size, fractions of the mean radius)
    but at least MIN_LINE_PX (walls and watched contacts 2 px)."""
    radii = frame.radii
    mean_radius = float(radii.mean()) if len(radii) else 1.0
    width = mean_radius * scale  # pixels per mean radius
    diameters = 2.0 * radii
    ax.add_collection(EllipseCollection(
        diameters, diameters, np.zeros(len(radii)), units="xy", offsets=frame.positions,
        offset_transform=ax.transData, facecolors=disk_colors(frame, color_field) / 255.0,
        edgecolors=_rgb(DISK_EDGE_COLOR), linewidths=_points(max(0.3, DISK_EDGE_WIDTH * width)),
        zorder=1), autolim=False)
    if forces:
        klass = force_classes(frame.contact_force)
        kind = np.clip(frame.contact_kind, 0, len(CONTACT_KINDS) - 1)
        lines = [max(MIN_LINE_PX, force_class_thickness(k, mean_radius) * scale) for k in range(FORCE_CLASSES)]
        # every border first, so that no border cuts a line where lines meet at a disk's centre
        for k in range(FORCE_CLASSES):
            _add_segments(ax, frame.contacts[klass == k], (255, 255, 255), lines[k] * (1.0 + 2.0 * FORCE_BORDER), 2)
        for k in range(FORCE_CLASSES):  # the strongest drawn last, on top
            for code, (_, color) in enumerate(CONTACT_KINDS):
                _add_segments(ax, frame.contacts[(klass == k) & (kind == code)], color, lines[k], 2)
    watched_width = max(2.0, WATCHED_THICKNESS * width)
    _add_segments(ax, frame.watched, (255, 255, 255), watched_width + 2.0, 3)
    for code in np.unique(frame.watched_index % len(WATCHED_COLORS)):
        _add_segments(ax, frame.watched[frame.watched_index % len(WATCHED_COLORS) == code], WATCHED_COLORS[code],
                      watched_width, 3)
    tips = frame.positions + radii[:, None] * np.column_stack([np.cos(frame.angles), np.sin(frame.angles)])
    _add_segments(ax, np.stack([frame.positions, tips], axis=1), SPOKE_COLOR,
                  max(MIN_LINE_PX, SPOKE_WIDTH * width), 3)
    _add_segments(ax, frame.walls, WALL_COLOR, max(2.0, WALL_WIDTH * width), 4, capstyle="projecting")
    for text, x, y in frame.labels:
        ax.text(x, y, text, ha="center", va="top", color=TEXT_COLOR,
                fontsize=max(MIN_EM, LABEL_SIZE * width) * POINTS_PER_PIXEL)
    if frame.cell is not None:
        _add_segments(ax, cell_outline(frame.cell), CELL_COLOR, max(1.5, CELL_WIDTH * width), 4, dashes=(6.0, 4.0))


def _draw_legend(ax: Axes, layout: _Layout, blocks: list[list[_Row]]) -> None:
    """The blocks one under the other (a column) or side by side (a strip), in pixels, y down."""
    em = layout.em
    ax.set_xlim(0.0, layout.legend[2])
    ax.set_ylim(layout.legend[3], 0.0)
    x = y = LEGEND_PAD * em
    for block in blocks:
        top = y
        for row in block:
            row.draw(ax, x, y, em)
            y += row.height * em
        if layout.column:
            y += BLOCK_GAP * em
        else:
            x += (_block_size(block)[0] + BLOCK_GAP) * em
            y = top


def render_image(frame: SceneFrame, size=(1280, 720), color_field: str = "rotation", forces: bool = True,
                 caption: str = "", bounds: tuple[float, float, float, float] | None = None,
                 watched_labels: Sequence[str] = ()) -> np.ndarray:
    """The picture of ``frame``: (H, W, 3) uint8 RGB for ``size`` = (W, H) pixels.

    ``color_field`` is one of :data:`granlab.app.media.drawing.COLOR_FIELDS`; ``forces`` draws the force
    network; ``caption`` is written above the legend (its first line in bold); the frame's
    watched contacts are named in the legend by ``watched_labels`` (in the order of the watch
    list: the k-th in the k-th colour); ``bounds`` (xmin, xmax, ymin, ymax, in
    lengths) is the region shown (default :func:`granlab.app.media.drawing.frame_bounds` of the frame; a movie
    passes the union over its frames so the packing stays put).
    """
    size = check_size(size)
    check_color_field(color_field)
    frame = _walls_cut_at_corners(frame)
    bounds = frame_bounds(frame) if bounds is None else bounds
    fig = Figure(figsize=(size[0] / DPI, size[1] / DPI), dpi=DPI, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    blocks = _legend_blocks(frame, color_field, forces, caption, watched_labels)
    layout = _layout(size, bounds, blocks)
    packing = _axes(fig, layout.packing, size)
    packing.set_xlim(*layout.limits[:2])
    packing.set_ylim(*layout.limits[2:])
    _draw_packing(packing, frame, color_field, forces, layout.scale)
    _draw_legend(_axes(fig, layout.legend, size), layout, blocks)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


def png_name(out: Path, number: int) -> Path:
    """The file of frame ``number`` when several frames are written as pictures: ``STEM_00012.png``."""
    return out.with_name(f"{out.stem}_{number:05d}.png")


def write_movie(frames: Iterable[tuple[SceneFrame, str]], out: Path, size=(1280, 720), color_field: str = "rotation",
                forces: bool = True, fps: float = 10.0, bounds: tuple[float, float, float, float] | None = None,
                numbers: Iterable[int] | None = None, watched_labels: Sequence[str] = ()) -> int:
    """Render (frame, caption) pairs into ``out`` and return how many frames were written.

    By the suffix of ``out``: ``.gif`` an animated GIF looping for ever (assembled in memory,
    about 2.8 MB per 1280x720 frame, and delays in whole hundredths of a second: 30 fps plays
    at 33); ``.mp4`` H.264 (yuv420p, CRF 18; width and height must be even, odd sizes are
    refused); ``.png`` the picture, or for more than one frame one picture per frame next to
    ``out``, named ``STEM_00012.png`` by ``numbers`` (default 0, 1, 2, ...; :func:`render_run`
    passes the frames' indices in the run file), ``out`` itself then not written.
    ``bounds`` is the region shown in every frame; by default the union of the frames' bounds,
    for which the frames are first all read into memory. ``watched_labels``: see :func:`render_image`.
    """
    out = Path(out)
    suffix = check_out(out)
    size = check_size(size, suffix=suffix)
    check_color_field(color_field)
    fps = check_fps(fps)
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        raise ParameterError("frames", "nothing", "at least one (SceneFrame, caption) pair")
    frames = itertools.chain([first], frames)
    if bounds is None:
        frames = list(frames)
        bounds = union_bounds(frame for frame, _ in frames)
    images = (render_image(frame, size, color_field, forces, caption, bounds, watched_labels)
              for frame, caption in frames)
    if suffix == ".gif":
        return _write_gif(images, out, fps)
    if suffix == ".mp4":
        return _write_mp4(images, out, size, fps)
    return _write_pngs(images, out, itertools.count() if numbers is None else iter(numbers))


def _write_pngs(images: Iterator[np.ndarray], out: Path, numbers: Iterator[int]) -> int:
    from PIL import Image

    # Pillow itself, as for GIFs
    first = next(images)
    second = next(images, None)
    if second is None:
        Image.fromarray(first).save(out)
        return 1
    count = 0
    for count, image in enumerate(itertools.chain([first, second], images), 1):
        Image.fromarray(image).save(png_name(out, next(numbers)))
    return count


def _write_gif(images: Iterator[np.ndarray], out: Path, fps: float) -> int:
    from PIL import Image

    # Pillow itself (not through imageio, whose writer retries a failed write when collected)
    frames = [Image.fromarray(image) for image in images]
    frames[0].save(out, save_all=True, append_images=frames[1:], duration=1000.0 / fps, loop=0)
    return len(frames)


def _write_mp4(images: Iterator[np.ndarray], out: Path, size: tuple[int, int], fps: float) -> int:
    import imageio_ffmpeg

    # macro_block_size 2: yuv420p's own constraint; imageio-ffmpeg's default of 16 would
    # resize 1920x1080 to 1920x1088.
    writer = imageio_ffmpeg.write_frames(str(out), size, fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                                         quality=None, macro_block_size=2, ffmpeg_log_level="quiet",
                                         output_params=["-crf", "18", "-movflags", "+faststart"])
    writer.send(None)
    count = 0
    try:
        for count, image in enumerate(images, 1):
            writer.send(np.ascontiguousarray(image))
    finally:
        writer.close()
    # ffmpeg's own failure (a full disk as it writes the index) is only in its log, kept quiet: the
    # file is read back
    try:
        frames, _ = imageio_ffmpeg.count_frames_and_secs(str(out))
    except (RuntimeError, OSError):
        frames = -1
    if frames != count:
        raise OutputError(f"ffmpeg could not finish the movie ({count} frames sent, {max(frames, 0)} in the "
                          f"file): is the disk full?")
    return count


def run_frames(f, indices: Iterable[int]) -> Iterator[tuple[SceneFrame, str]]:
    """(SceneFrame, caption) of each frame ``indices`` of an open GranLab run file ``f``, with
    the contacts the lab watched (a lab run's), its views named (the closed path's pairs) and the
    phase of its protocol in the caption."""
    walls = h5md.run_walls(f)
    normals = np.array([wall.normal for wall in walls], dtype=float).reshape(-1, 2)
    protocol = h5md.run_protocol(f)
    watched = [tuple(pair) for pair in protocol.get("watched", [])]
    groups = [tuple(group) for group in protocol.get("views", [])]
    for index in indices:
        raw = h5md.read_frame(f, index)
        yield (build_frame([(FrameData.from_run_frame(raw, normals), (0.0, 0.0))], [watched], groups),
               frame_caption(raw["time"], raw["step"], raw.get("lab_phase", "")))


MOVIE_CYCLES = 10
MOVIE_FRAMES = 100
"""A movie's default length: the last MOVIE_CYCLES load cycles (or clock units) of a run that
names its cycle, else its last MOVIE_FRAMES frames: a short clip for a slide, in a minute or so."""


def default_movie_frames(f, count: int) -> list[int]:
    """The frames of a movie made without ``--frames``: those of the last MOVIE_CYCLES cycles
    (the lab's ``cycle_time`` or a study's ``period`` in the file's protocol), else the last
    MOVIE_FRAMES."""
    protocol = h5md.run_protocol(f)
    cycle = protocol.get("cycle_time") or protocol.get("period")
    if isinstance(cycle, (int, float)) and cycle > 0:
        times = f["particles/all/position/time"][:count]
        first = int(np.searchsorted(times, times[-1] - MOVIE_CYCLES * cycle - 1e-9 * abs(cycle)))
        return list(range(min(first, count - 2) if count > 1 else 0, count))
    return list(range(max(0, count - MOVIE_FRAMES), count))


def render_run(path, out, frames=None, size="1280x720", color_field: str = "rotation", forces: bool = True,
               fps=10.0, force: bool = False, progress: Callable[[int, int], None] | None = None) -> dict:
    """Render frames of a GranLab run file into ``out`` (:func:`write_movie`); what
    ``granlab render`` calls, so errors name its options. Existing pictures or movies are
    written over only with ``force``.

    ``frames``: see :func:`granlab.engine.io.frame_selection.select_frames`; default the last frame
    for ``.png``, the last ten cycles (:func:`default_movie_frames`) for a movie.
    ``progress(done, total)`` is called as frames are rendered. ``size`` (W, H) or ``"WxH"``;
    ``fps`` frames per second of a movie. The axes are the union of the selected frames' bounds
    (read in a first pass, the frames rendered in a second). Returns ``out``, the ``files``
    written, ``frames`` (their count), ``indices`` (first and last), ``size`` [W, H], ``color``,
    ``forces``, ``fps`` and ``seconds_per_frame``.
    """
    start = time.perf_counter()
    out = Path(out)
    suffix = check_out(out, "--out")
    size = check_size(size, "--size", suffix)
    check_color_field(color_field, "--color")
    fps = check_fps(fps, "--fps")
    with h5md.open_run(path) as f:
        count = h5md.frame_count(f)
        h5md.require_run_file(f, "render")
        if count == 0:
            raise h5md.RunFileError(f"{str(path)!r} holds no complete frame")
        if frames is None:
            indices = [count - 1] if suffix == ".png" else default_movie_frames(f, count)
        else:
            indices = select_frames(frames, count, "--frames")
        targets = [png_name(out, index) for index in indices] if suffix == ".png" and len(indices) > 1 else [out]
        for target in targets:
            check_output(target, force=force)
        bounds = union_bounds(frame for frame, _ in run_frames(f, indices))
        frames_read = run_frames(f, indices)
        if progress is not None:
            frames_read = reporting(frames_read, len(indices), progress)
        with staged(out.parent, last=[out.name]) as folder:
            written = write_movie(frames_read, folder / out.name, size, color_field, forces, fps, bounds, indices,
                                  h5md.run_protocol(f).get("watched_labels", []))
        if progress is not None:
            progress(len(indices), len(indices))
    return {"run_file": str(path), "out": str(out), "files": [str(target) for target in targets], "frames": written,
            "indices": [indices[0], indices[-1]], "size": list(size), "color": color_field, "forces": forces,
            "fps": fps, "seconds_per_frame": (time.perf_counter() - start) / written}


def print_summary(result: dict) -> None:
    """What ``granlab render`` prints without ``--json``."""
    files = result["files"]
    where = files[0] if len(files) == 1 else f"{len(files)} pictures {Path(files[0]).name} .. {Path(files[-1]).name}"
    first, last = result["indices"]
    frames = f"frame {first}" if result["frames"] == 1 else f"{result['frames']} frames ({first}..{last})"
    print(f"wrote {where}: {frames} of {result['run_file']}, {result['size'][0]}x{result['size'][1]}, "
          f"disks by {result['color']}{', forces' if result['forces'] else ''}; "
          f"{result['seconds_per_frame']:.2f} s a frame")
