"""The lab's colours told apart by everyone, checked by simulating the common colour-vision
deficiencies rather than by eye.

Every group of colours shown together whose members a legend names apart differs pairwise by a CIEDE2000
ΔE of at least :data:`NAMED_APART`, in normal vision and as protanopes, deuteranopes and tritanopes
see them; a pair may instead differ by its dash or marker, where the test names it. The continuous
maps keep a quarter turn of rotation, and the quarters of pressure and of the q–γ plot's cycles,
apart the same way. The legends show the colours drawn.

Simulation: Machado, Oliveira & Fernandes, "A physiologically-based model for simulation of
color vision deficiency", IEEE TVCG 15(6), 1291-1298 (2009), the matrices for severity 1.0
(dichromacy), applied to linear RGB. CIELAB under D65 from sRGB; CIEDE2000 after Sharma, Wu &
Dalal, Color Res. Appl. 30(1), 21-30 (2005), checked against their published pairs.
"""

from itertools import combinations

import numpy as np
import pytest

from granlab.app.lab import plots
from granlab.app.lab.scene import _WIRE_TABLES, srgb_to_linear
from granlab.app.media import drawing
from granlab.engine.params import TANGENTIAL
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS

NAMED_APART = 10.0
"""The least ΔE2000 between two colours a legend names apart. ΔE2000 ≈ 1 is a just-noticeable
difference between large patches side by side; these are lines a few pixels wide and 7-pixel
markers, seen across a classroom on a projector and matched with a legend elsewhere on the
screen, which takes several times more (the noticeable difference grows as marks shrink: Stone,
Szafir & Setlur, Color and Imaging Conference 2014). 10 is also about what the palettes made
for colour-blind readers reach under this simulation (Okabe–Ito's worst pair 10.9, Paul Tol's
muted 11.5): as much as eight to fifteen colours can give."""

MACHADO = {
    "protanopia": np.array([[0.152286, 1.052583, -0.204868],
                            [0.114503, 0.786281, 0.099216],
                            [-0.003882, -0.048116, 1.051998]]),
    "deuteranopia": np.array([[0.367322, 0.860646, -0.227968],
                              [0.280085, 0.672501, 0.047413],
                              [-0.011820, 0.042940, 0.968881]]),
    "tritanopia": np.array([[1.255528, -0.076749, -0.178779],
                            [-0.078411, 0.930809, 0.147602],
                            [0.004733, 0.691367, 0.303900]]),
}
VISIONS = ("normal", *MACHADO)

_SRGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                         [0.2126729, 0.7151522, 0.0721750],
                         [0.0193339, 0.1191920, 0.9503041]])
_WHITE = _SRGB_TO_XYZ.sum(axis=1)  # D65, the white of sRGB


def rgb(color) -> tuple[int, int, int]:
    """An sRGB triple of a ``#rrggbb`` string or of a triple."""
    if isinstance(color, str):
        return tuple(int(color[k:k + 2], 16) for k in (1, 3, 5))
    return tuple(int(c) for c in color)


def seen(colors, vision: str) -> np.ndarray:
    """(..., 3) CIELAB of sRGB ``colors`` (0-255) as ``vision`` sees them."""
    c = np.asarray(colors, dtype=float) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    if vision != "normal":
        linear = np.clip(linear @ MACHADO[vision].T, 0.0, 1.0)
    return lab(linear)


def lab(linear: np.ndarray) -> np.ndarray:
    t = (linear @ _SRGB_TO_XYZ.T) / _WHITE
    f = np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1)


def ciede2000(lab1, lab2) -> np.ndarray:
    """CIEDE2000 colour difference of CIELAB colours (..., 3), kL = kC = kH = 1."""
    L1, a1, b1 = np.moveaxis(np.asarray(lab1, dtype=float), -1, 0)
    L2, a2, b2 = np.moveaxis(np.asarray(lab2, dtype=float), -1, 0)
    c7 = ((np.hypot(a1, b1) + np.hypot(a2, b2)) / 2) ** 7
    g = 0.5 * (1 - np.sqrt(c7 / (c7 + 25.0 ** 7)))
    c1, c2 = np.hypot((1 + g) * a1, b1), np.hypot((1 + g) * a2, b2)
    h1 = np.degrees(np.arctan2(b1, (1 + g) * a1)) % 360
    h2 = np.degrees(np.arctan2(b2, (1 + g) * a2)) % 360
    chromatic = c1 * c2 != 0  # a grey has no hue: its hue difference is 0
    dh = np.where(chromatic, (h2 - h1 + 180) % 360 - 180, 0.0)
    dH = 2 * np.sqrt(c1 * c2) * np.sin(np.radians(dh) / 2)
    mean_l, mean_c = (L1 + L2) / 2, (c1 + c2) / 2
    mean_h = np.where(~chromatic, h1 + h2, np.where(np.abs(h1 - h2) <= 180, (h1 + h2) / 2,
                                                    np.where(h1 + h2 < 360, (h1 + h2 + 360) / 2, (h1 + h2 - 360) / 2)))
    t = (1 - 0.17 * np.cos(np.radians(mean_h - 30)) + 0.24 * np.cos(np.radians(2 * mean_h))
         + 0.32 * np.cos(np.radians(3 * mean_h + 6)) - 0.20 * np.cos(np.radians(4 * mean_h - 63)))
    s_l = 1 + 0.015 * (mean_l - 50) ** 2 / np.sqrt(20 + (mean_l - 50) ** 2)
    s_c, s_h = 1 + 0.045 * mean_c, 1 + 0.015 * mean_c * t
    r_t = (-np.sin(np.radians(60 * np.exp(-(((mean_h - 275) / 25) ** 2))))
           * 2 * np.sqrt(mean_c ** 7 / (mean_c ** 7 + 25.0 ** 7)))
    dl, dc, dhh = (L2 - L1) / s_l, (c2 - c1) / s_c, dH / s_h
    return np.sqrt(dl ** 2 + dc ** 2 + dhh ** 2 + r_t * dc * dhh)


def difference(a, b, vision: str) -> float:
    return float(ciede2000(seen(rgb(a), vision), seen(rgb(b), vision)))


# --- the groups of colours shown together ---------------------------------------------------

LINE = ("line", ())
"""The style of a solid line: a group's entries are (colour, style); two entries of different
styles (a dash, a marker, a vertical mark) are told apart by it whatever their colours."""

_DASHES = {"solid": (), "dashed": (6,), "dotted": (2, 4), "dotdash": (2, 4, 6, 4), "dashdot": (6, 4, 2, 4)}
"""bokeh's named dash patterns, to compare a named dash with one given as numbers."""


def _dash(value) -> tuple:
    if isinstance(value, str):
        return _DASHES[value] if value in _DASHES else tuple(int(v) for v in value.split())
    return tuple(value)


def _figure_entries(fig) -> dict:
    """{legend label or glyph: (colour, style)} of the renderers of ``fig`` drawn in one colour
    (those coloured by a data column belong to the palettes checked on their own)."""
    labels = {id(r): getattr(item.label, "value", None) for legend in fig.legend for item in legend.items
              for r in item.renderers}
    entries = {}
    for k, renderer in enumerate(fig.renderers):
        glyph = renderer.glyph
        kind = type(glyph).__name__
        if kind == "Scatter":
            color, style = glyph.fill_color, (glyph.marker, ())
        else:
            # a vertical mark across the whole plot (a change of the physics) is no data line
            color, style = glyph.line_color, ("vertical" if kind == "VSpan" else "line", _dash(glyph.line_dash))
        if isinstance(color, str) and color.startswith("#"):
            entries[labels.get(id(renderer)) or f"{kind} {k}"] = (color, style)
    return entries


def scene_groups() -> dict:
    kinds = {name: (color, LINE) for name, color in drawing.CONTACT_KINDS}
    watched = {f"watched {k + 1}": (tuple(c), LINE) for k, c in enumerate(drawing.WATCHED_COLORS)}
    # the mechanism's arrows are drawn over the packing beside the contacts, after an analysis
    common = {**kinds, **watched, "spoke": (drawing.SPOKE_COLOR, LINE), "mechanism": (drawing.MECHANISM_COLOR, LINE)}
    return {"scene: contacts, watched, walls, spokes": {**common, "walls": (drawing.WALL_COLOR, LINE)},
            "scene: contacts, watched, periodic cell, spokes": {**common, "cell": (drawing.CELL_COLOR, LINE)},
            "watched contacts": watched}


def plot_groups() -> dict:
    groups = {}
    for name in [*plots.LINES, "strain-per-cycle", "coulomb-cone"]:
        entries = _figure_entries(plots.make_plot(name, "t", {}, reference_cycle=2).figure)
        if name == "coulomb-cone":
            # the paths, coloured per contact: the sliding marks (triangles) are drawn on them and
            # the cone is dashed, so only the paths' colours must differ among themselves
            entries.update({f"path {k + 1}": (tuple(c), LINE) for k, c in enumerate(drawing.WATCHED_COLORS)})
        groups[f"plot {name}"] = entries
    for name, fig in plots.AnalysisFigures().figures.items():
        groups[f"analysis {name}"] = _figure_entries(fig)
    return groups


MODELS_OVERLAID = {frozenset(("alpha", "angle")), frozenset(("cundall-strack", "lammps"))}
"""Pairs of tangential models whose lines lie on each other (plots.MODEL_LINES): the later one's dash
shows only where its colour differs from the line under it, so these must differ in colour."""


def model_group() -> dict:
    return {name: (color, ("line", _dash(line))) for name, (color, line) in plots.MODEL_STYLES.items()}


def palette_groups() -> dict:
    status = {name: (color, LINE) for name, color in drawing.STATUS_LEGEND.values()}
    return {"contact status (Coulomb-cone marks)": status,
            "coordination z = 0..6+": {f"z={k}": (tuple(c), LINE) for k, c in enumerate(drawing.COORDINATION_COLORS)},
            "sliding disks": {f"row {k}": (tuple(c), LINE) for k, c in enumerate(drawing.SLIDING_DISK_COLORS)}}


def all_groups() -> dict:
    """Every group with a pair that must differ in colour (a plot of one line beside the vertical
    marks of changes has none)."""
    groups = {**scene_groups(), **palette_groups(), **plot_groups(), "tangential models": model_group()}
    return {name: entries for name, entries in groups.items()
            if any(must_differ(name, a, b, entries) for a, b in combinations(entries, 2))}


def must_differ(group: str, a: str, b: str, entries: dict) -> bool:
    """Whether the pair must differ in colour: it is drawn alike (or overlaid)."""
    if group == "tangential models" and frozenset((a, b)) in MODELS_OVERLAID:
        return True
    return entries[a][1] == entries[b][1]


def worst_pair(group: str, entries: dict, vision: str) -> tuple[float, str, str]:
    """The least ΔE2000 in ``vision`` among the pairs of ``entries`` that must differ in colour."""
    pairs = [(difference(entries[a][0], entries[b][0], vision), a, b)
             for a, b in combinations(entries, 2) if must_differ(group, a, b, entries)]
    return min(pairs, default=(float("inf"), "", ""))


# --- the tests ------------------------------------------------------------------------------

SHARMA_PAIRS = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, -1.3802, -84.2814), (50.0, 0.0, -82.7485), 1.0000),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.49, -0.001), (50.0, -2.49, 0.0009), 7.1792),  # hue angles either side of 0°
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
    ((22.7233, 20.0904, -46.694), (23.0331, 14.973, -42.5619), 2.0373),  # the blue rotation term
    ((2.0776, 0.0795, -1.135), (0.9033, -0.0636, -0.5514), 0.9082),
]


def test_ciede2000_and_the_simulation_agree_with_their_references():
    first, second, want = (np.array(column) for column in zip(*SHARMA_PAIRS))
    assert np.abs(ciede2000(first, second) - want).max() < 1e-4
    assert np.abs(ciede2000(second, first) - want).max() < 1e-4
    assert np.allclose(seen((255, 0, 0), "normal"), (53.24, 80.09, 67.20), atol=0.01)
    for vision in MACHADO:
        # a dichromat sees greys as everyone does, and confuses the colours of their confusion line
        assert difference((128, 128, 128), (128, 128, 128), vision) == 0
        assert np.abs(seen((200, 200, 200), vision) - seen((200, 200, 200), "normal")).max() < 0.1
    assert difference((255, 0, 0), (0, 255, 0), "normal") > 80
    assert difference((170, 120, 0), (130, 135, 0), "deuteranopia") < 3  # orange and olive


GROUPS = all_groups()


@pytest.mark.parametrize("group", list(GROUPS))
@pytest.mark.parametrize("vision", VISIONS)
def test_colours_shown_together_are_told_apart(group, vision):
    entries = GROUPS[group]
    value, a, b = worst_pair(group, entries, vision)
    assert value >= NAMED_APART, f"{group}, {vision}: {a} {entries[a][0]} and {b} {entries[b][0]}: ΔE2000 {value:.1f}"


def quarter_turn(lut: np.ndarray, vision: str) -> np.ndarray:
    """ΔE2000 between the colour of each angle and that of the angle a quarter turn on."""
    colors = seen(lut, vision)
    return ciede2000(colors, np.roll(colors, -len(lut) // 4, axis=0))


@pytest.mark.parametrize("vision", VISIONS)
def test_a_quarter_turn_changes_a_disks_colour(vision):
    """Every angle, not only the quarter points: a rainbow's quarter points can differ while a
    deuteranope sees θ and θ + π/2 alike in between (the former map: ΔE2000 3.0 at θ = 3.5)."""
    assert quarter_turn(drawing.ROTATION_LUT, vision).min() >= NAMED_APART


def quarters(table: np.ndarray, vision: str) -> float:
    """The least ΔE2000 between neighbouring quarter points (0, 1/4, ... 1) of a sequential map."""
    points = seen(table[np.linspace(0, len(table) - 1, 5).round().astype(int)], vision)
    return float(ciede2000(points[:-1], points[1:]).min())


@pytest.mark.parametrize("vision", VISIONS)
def test_sequential_maps_grow_in_lightness(vision):
    """Pressure (viridis) and the q–γ plot's cycles: lightness moves one way in every vision, so
    more is always lighter (or darker), and the map's quarter points are named apart. A step may go
    back by 0.1 L*: the 8-bit rounding of an interpolated table. The q–γ plot draws the cycles
    older than those it shades in grey: its lightest shade is named apart from that grey."""
    mapper = plots.LoadStrainPlot().mapper
    blues = np.array([rgb(c) for c in mapper.palette])
    for table in (drawing.PRESSURE_LUT, blues):
        lightness = seen(table, vision)[:, 0]
        steps = np.diff(lightness) * np.sign(lightness[-1] - lightness[0])
        assert steps.min() > -0.1
        assert quarters(table, vision) >= NAMED_APART
    assert difference(mapper.low_color, blues[0], vision) >= NAMED_APART


def test_the_legends_show_the_colours_drawn():
    """The scene's legend, the scene's wire colours and the plots' legends read the same
    constants: a colour changed in drawing.py changes everywhere."""
    html = drawing.legend_html("coordination", ["0–1", "2–3"], walls=True, cell=True, mechanism=True)
    shown = [color for _, color in drawing.CONTACT_KINDS] + list(drawing.WATCHED_COLORS[:2]) + list(
        drawing.COORDINATION_COLORS) + [drawing.WALL_COLOR, drawing.CELL_COLOR, drawing.SPOKE_COLOR,
                                        drawing.MECHANISM_COLOR]
    for color in shown:
        assert drawing.hex_color(color) in html
    assert drawing.hex_color(drawing.SLIDING_DISK_COLORS[1]) in drawing.legend_html("sliding", [], False, False)
    rotation = drawing.legend_html("rotation", [], False, False)
    assert all(drawing.hex_color(c) in rotation for c in drawing.ROTATION_LUT[::len(drawing.ROTATION_LUT) // 12])
    assert np.array_equal(_WIRE_TABLES["watched"], srgb_to_linear(drawing.WATCHED_COLORS))
    assert np.array_equal(_WIRE_TABLES["contact kind"], srgb_to_linear([c for _, c in drawing.CONTACT_KINDS]))
    marks = _figure_entries(plots.make_plot("coulomb-cone", "t", {}).figure)
    for code in (STATUS_SLIDE_POS, STATUS_SLIDE_NEG):
        label, color = drawing.STATUS_LEGEND[code]
        assert marks[label][0] == color
    springs = _figure_entries(plots.make_plot("springs", "t", {}).figure)
    assert {m.label: springs[m.label][0] for m in TANGENTIAL.values()} == {
        m.label: plots.MODEL_STYLES[m.name][0] for m in TANGENTIAL.values()}
