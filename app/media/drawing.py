"""The colours of a picture of the lab, shared by the live 3D scene (:mod:`granlab.app.lab.scene`), the
movies of ``granlab render`` (:mod:`granlab.app.media.render`) and the legends.

A picture is a :class:`granlab.engine.frames.SceneFrame` (its geometry, in the engine so that the
headless export writes the same fields); here are its colour fields, palettes, line classes,
caption, bounds and legends. Colours are sRGB triples as they should appear on screen. Nothing
here imports viser or matplotlib.
"""

from __future__ import annotations

import numpy as np

from granlab.engine.frames import SceneFrame
from granlab.engine.state import STATUS_COHESIVE, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

COLOR_FIELDS = ("rotation", "coordination", "pressure", "sliding")

FORCE_CLASSES = 5
"""Width classes of the force network: class k holds k/K <= |F|/max|F| < (k+1)/K
(and the largest force, in class K - 1)."""

MAX_FORCE_THICKNESS = 0.4
"""Thickness of the strongest class, as a fraction of the mean radius; class k
is (k + 1)/K of it (a packing of 16 disks, its forces nearly all in the top class, still shows
most of each disk)."""

WATCHED_THICKNESS = 0.3
"""Thickness of a watched contact's line, as a fraction of the mean radius: drawn over the force
network, on a strong force's line it is its coloured core."""

# The lines drawn over the packing, told apart by everyone (tests/test_colour_vision.py): the
# contact kinds, the watched contacts (WATCHED_COLORS) and the mechanism's arrows are Okabe–Ito's
# and Paul Tol's colours, each moved by at most 7 ΔE2000 so that any two of them, or one of them and
# the walls, the cell or the spokes, differ by ΔE2000 >= 11.9 also as protanopes, deuteranopes and
# tritanopes see them (the walls and the spokes, greys, by 11.1).
COMPRESSIVE_COLOR = (184, 9, 1)
TENSILE_COLOR = (1, 102, 201)
SLIDING_CONTACT_COLOR = (240, 176, 46)
SPOKE_COLOR = (25, 25, 25)
WALL_COLOR = (60, 60, 60)
CELL_COLOR = (68, 71, 71)
MECHANISM_COLOR = (190, 115, 148)
CONTACT_KINDS = (("compressive", COMPRESSIVE_COLOR), ("tensile (cohesion or dashpot)", TENSILE_COLOR),
                 ("sliding", SLIDING_CONTACT_COLOR))
"""Name and colour of each contact kind of :attr:`granlab.engine.frames.SceneFrame.contact_kind` (0, 1, 2)."""

WATCHED_COLORS = np.array(
    [(251, 77, 114), (38, 146, 102), (2, 178, 255), (79, 14, 160), (145, 136, 0), (149, 74, 124), (15, 108, 67),
     (146, 170, 196)],
    dtype=np.uint8,
)
"""Colour of the k-th watched contact (cycled): the same in the scene and in the Coulomb-cone
plot, so a path on the plot can be found in the packing. None of them is a contact kind's; none
is lighter than L* = 70, so that a path shows on the plot's white."""

STATUS_LEGEND = {STATUS_STICK: ("non-sliding", "#555555"), STATUS_SLIDE_POS: ("slides, +μ side", "#f59b00"),
                 STATUS_SLIDE_NEG: ("slides, −μ side", "#b35a00"),
                 STATUS_COHESIVE: ("attracted at a distance", "#1e5adc")}
"""Name and colour of each contact status in the plots of watched contacts."""

COORDINATION_COLORS = np.array(
    [
        (200, 200, 200),  # 0 contacts: rattler
        (240, 228, 66),  # 1
        (230, 159, 0),  # 2
        (213, 94, 0),  # 3
        (204, 121, 167),  # 4
        (86, 180, 233),  # 5
        (0, 158, 115),  # 6 or more
    ],
    dtype=np.uint8,
)
"""Colour of a disk with z contacts, z = 0..6 (6 stands for 6 or more): Okabe–Ito's colours, in
the order of the hues before them (yellow, orange, red, purple, blue, green)."""

SLIDING_DISK_COLORS = np.array([(170, 190, 215), (245, 140, 0)], dtype=np.uint8)
"""Colour of a disk without (row 0) and with (row 1) a sliding contact."""

LUT_SIZE = 256


def _lookup_table(anchors: list[tuple[int, int, int]], cyclic: bool) -> np.ndarray:
    """(256, 3) uint8 table interpolating the RGB anchors linearly (and back to
    the first anchor if cyclic)."""
    colors = np.asarray(anchors + anchors[:1] if cyclic else anchors, dtype=np.float64)
    stops = np.linspace(0.0, 1.0, len(colors))
    samples = np.arange(LUT_SIZE) / (LUT_SIZE if cyclic else LUT_SIZE - 1)
    table = np.stack([np.interp(samples, stops, colors[:, c]) for c in range(3)], axis=1)
    return np.round(table).astype(np.uint8)


ROTATION_LUT = _lookup_table(
    [(209, 209, 209), (220, 181, 241), (192, 140, 224), (149, 114, 170), (114, 114, 114), (98, 138, 83),
     (115, 176, 95), (164, 207, 148)],
    cyclic=True,
)
"""Cyclic map of theta: entry floor(256 theta / 2 pi) mod 256. A disk at rest is light grey, a
turn anticlockwise makes it purple, clockwise green, half a turn dark grey: the anchors are
L* = 66 + 18 cos theta, (a*, b*) = (35, -35) sin theta, a circle that each colour-vision
deficiency sees as a loop (a rainbow does not: a deuteranope sees some angles a quarter turn apart alike)."""

PRESSURE_LUT = _lookup_table(
    [(68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141),
     (39, 173, 129), (92, 200, 99), (170, 220, 50), (253, 231, 37)],
    cyclic=False,
)
"""Sequential map (viridis anchors) of p / max p: entry round(255 p / max p)."""

PALETTES = {"rotation": ROTATION_LUT, "coordination": COORDINATION_COLORS, "pressure": PRESSURE_LUT,
            "sliding": SLIDING_DISK_COLORS}
"""The table each colour field indexes (sRGB)."""


def color_index(frame: SceneFrame, field: str, index: np.ndarray, scratch: np.ndarray) -> None:
    """Rows of ``PALETTES[field]`` for each disk of ``frame`` into ``index`` (N,) intp, using
    ``scratch`` (N,) float64 (both preallocated: a lab-sized frame is coloured without allocating)."""
    if field == "rotation":
        np.multiply(frame.angles, LUT_SIZE / (2.0 * np.pi), out=scratch)
        np.floor(scratch, out=scratch)
        np.mod(scratch, LUT_SIZE, out=scratch)
        index[:] = scratch
    elif field == "coordination":
        np.clip(frame.coordination, 0, len(COORDINATION_COLORS) - 1, out=index, casting="unsafe")
    elif field == "pressure":
        top = float(frame.pressure.max()) if len(frame.pressure) else 0.0
        np.multiply(frame.pressure, (LUT_SIZE - 1) / top if top > 0.0 else 0.0, out=scratch)
        np.rint(scratch, out=scratch)
        np.clip(scratch, 0, LUT_SIZE - 1, out=scratch)
        index[:] = scratch
    elif field == "sliding":
        index[:] = frame.sliding
    else:
        raise ValueError(f"color_field {field!r} is not allowed: one of {', '.join(COLOR_FIELDS)}")


def disk_colors(frame: SceneFrame, field: str) -> np.ndarray:
    """(N, 3) uint8 sRGB colour of each disk for ``field``."""
    n = len(frame.radii)
    index = np.zeros(n, dtype=np.intp)
    color_index(frame, field, index, np.zeros(n))
    return PALETTES[field][index]


def force_classes(contact_force: np.ndarray, classes: int = FORCE_CLASSES) -> np.ndarray:
    """(M,) int class of each contact: min(K - 1, floor(K |F| / max|F|)), all 0
    when every force is 0. Thickness grows with the class."""
    top = float(contact_force.max()) if len(contact_force) else 0.0
    if top <= 0.0:
        return np.zeros(len(contact_force), dtype=np.intp)
    return np.minimum((contact_force * (classes / top)).astype(np.intp), classes - 1)


def force_class_thickness(klass: int, mean_radius: float) -> float:
    """World thickness of force class k: (k + 1)/K x MAX_FORCE_THICKNESS x mean radius."""
    return (klass + 1) / FORCE_CLASSES * MAX_FORCE_THICKNESS * mean_radius


def frame_caption(sim_time: float, step: int, phase: str = "") -> str:
    """The caption of a picture at simulated time ``sim_time`` (four significant digits, never an
    exponent) and step ``step``, under the protocol's ``phase`` if there is one:
    ``cycle 12 · q = 0.312, rising`` then ``t = 12.5, step 16250`` on a line of its own."""
    digits = np.format_float_positional(sim_time, precision=4, unique=True, fractional=False, trim="-")
    return (f"{phase}\n" if phase else "") + f"t = {digits}, step {step}"


LABEL_SIZE = 0.45
LABEL_HEIGHT = 1.5
"""A label under disks (the closed path's pairs) is written LABEL_SIZE mean radii high and takes
LABEL_HEIGHT of them under the disks; a character is about 0.6 of its height wide."""


def frame_bounds(frame: SceneFrame) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the disks, walls, cell outline and labels."""
    xs = [frame.positions[:, 0] - frame.radii, frame.positions[:, 0] + frame.radii,
          frame.walls[:, :, 0].ravel()]
    ys = [frame.positions[:, 1] - frame.radii, frame.positions[:, 1] + frame.radii,
          frame.walls[:, :, 1].ravel()]
    if frame.labels:
        mean_radius = float(frame.radii.mean())
        half = np.array([0.3 * LABEL_SIZE * mean_radius * len(text) for text, _, _ in frame.labels])
        x = np.array([x for _, x, _ in frame.labels])
        xs += [x - half, x + half]
        ys.append(np.array([y - LABEL_HEIGHT * mean_radius for _, _, y in frame.labels]))
    if frame.cell is not None:
        xs.append(np.array([0.0, frame.cell[0]]))
        ys.append(np.array([0.0, frame.cell[1]]))
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    if len(x) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    return (float(x.min()), float(x.max()), float(y.min()), float(y.max()))


def hex_color(rgb) -> str:
    """``#rrggbb`` of an sRGB triple."""
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb))


def _swatch(color: str, text: str, line: bool = False) -> str:
    shape = "width:18px;height:5px;border-radius:2px" if line else "width:12px;height:12px;border-radius:50%"
    return (f'<span style="display:inline-flex;align-items:center;margin-right:10px;white-space:nowrap">'
            f'<span style="display:inline-block;{shape};background:{color};margin-right:4px"></span>{text}</span>')


def _gradient(table: np.ndarray, left: str, right: str) -> str:
    stops = ", ".join(hex_color(c) for c in table[:: max(1, len(table) // 12)])
    return (f'<span style="display:inline-flex;align-items:center;margin-right:10px">{left}'
            f'<span style="display:inline-block;width:90px;height:10px;margin:0 4px;'
            f'background:linear-gradient(to right, {stops})"></span>{right}</span>')


DISK_LEGENDS = {
    "rotation": lambda: "disk colour = rotation angle θ: " + _gradient(ROTATION_LUT, "0", "2π (cyclic)"),
    "coordination": lambda: "disk colour = contacts z: " + "".join(
        _swatch(hex_color(c), f"{k}{'+' if k == len(COORDINATION_COLORS) - 1 else ''}")
        for k, c in enumerate(COORDINATION_COLORS)),
    "pressure": lambda: "disk colour = pressure on the disk: " + _gradient(PRESSURE_LUT, "0", "its largest"),
    "sliding": lambda: "disk colour: " + _swatch(hex_color(SLIDING_DISK_COLORS[0]), "no sliding contact")
    + _swatch(hex_color(SLIDING_DISK_COLORS[1]), "a contact sliding"),
}


def legend_html(color_field: str, watched_labels: list[str], walls: bool, cell: bool, mechanism: bool = False) -> str:
    """The legend of the 3D scene: what the disk colours, the spokes, the force lines (kind and
    width), the watched contacts, the boundary and the mechanism arrows mean."""
    forces = "".join(_swatch(hex_color(color), name, line=True) for name, color in CONTACT_KINDS)
    watched = "".join(_swatch(hex_color(WATCHED_COLORS[k % len(WATCHED_COLORS)]), label, line=True)
                      for k, label in enumerate(watched_labels))
    boundary = (_swatch(hex_color(WALL_COLOR), "walls", line=True) if walls else "") + \
        (_swatch(hex_color(CELL_COLOR), "periodic cell", line=True) if cell else "")
    rows = [DISK_LEGENDS[color_field]() + _swatch(hex_color(SPOKE_COLOR), "spoke: the disk's rotation", line=True),
            "force network: " + forces + "line width ∝ |F| " + boundary]
    if watched:
        rows.append("watched contacts (as in the Coulomb-cone plot): " + watched)
    if mechanism:
        rows.append(_swatch(hex_color(MECHANISM_COLOR), "arrows: the mechanism the stiffness analysis found "
                                                        "(where the disks were then)", line=True))
    return "<div class='scene-legend' style='font-size:12px;line-height:1.7'>" + "<br>".join(rows) + "</div>"
