"""``html`` (a handout): one HTML page that replays the run in a browser opened from disk, with no
server and no request off the page (its script, styles and data are in it). The scene as the lab
draws it (the disks in the lab's colour fields with their legend, their spokes, the force network,
the walls or the periodic cell, the watched contacts), the preset's plots where the run file holds
their series (a lab run; another run gets the energy budget, z and Φ of each frame and, if it was
cycled, the strain per cycle), a timeline that moves a marker on every plot, and the preset and
settings of the run. Coordinates are float32; frames (and long series) are thinned evenly to keep
the page under :data:`MAX_BYTES`, and the page says so.
"""

from __future__ import annotations

import base64
import json
import math
import tomllib
from pathlib import Path

import h5py
import numpy as np

from granlab.engine.analysis.ratchet import strain_fit
from granlab.engine.frames import cell_outline, group_labels, meeting_walls
from granlab.engine.io import h5md
from granlab.engine.observables import coordination, solid_fraction
from granlab.engine.params import TANGENTIAL
from granlab.engine.protocols.presets import PRESETS
from granlab.engine.protocols.measures import pair_codes
from granlab.engine.protocols.presets.base import CONTROL_SYMBOLS, setting_text
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS

MAX_BYTES = 9_000_000
"""What the embedded frames and series may take (base64 included): with the page's own 30 kB, a
handout stays under 10 MB, small enough to mail."""
TRAVEL = 3.0
"""A scene whose frames together span more than this many times one frame follows the packing."""
PLOT_POINTS = 40_000
"""Samples a plot keeps: more are thinned evenly (a browser draws 40 000 in a few milliseconds)."""

# The lab's colours (granlab.app.media.drawing, which the engine may not import: it is the layer
# above); tests/test_handout.py checks that they are the same.
ROTATION_ANCHORS = [(209, 209, 209), (220, 181, 241), (192, 140, 224), (149, 114, 170), (114, 114, 114), (98, 138, 83),
                    (115, 176, 95), (164, 207, 148)]
PRESSURE_ANCHORS = [(68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141), (39, 173, 129),
                    (92, 200, 99), (170, 220, 50), (253, 231, 37)]
COORDINATION_COLORS = [(200, 200, 200), (240, 228, 66), (230, 159, 0), (213, 94, 0), (204, 121, 167),
                       (86, 180, 233), (0, 158, 115)]
SLIDING_DISK_COLORS = [(170, 190, 215), (245, 140, 0)]
CONTACT_KINDS = [("compressive", (184, 9, 1)), ("tensile (cohesion or dashpot)", (1, 102, 201)),
                 ("sliding", (240, 176, 46))]
WATCHED_COLORS = [(251, 77, 114), (38, 146, 102), (2, 178, 255), (79, 14, 160), (145, 136, 0), (149, 74, 124),
                  (15, 108, 67), (146, 170, 196)]
LINE_COLORS = {"spoke": (25, 25, 25), "wall": (60, 60, 60), "cell": (68, 71, 71), "edge": (70, 70, 70)}
STATUS_MARKS = {STATUS_SLIDE_POS: ("slides, +μ side", "#f59b00", "up"),
                STATUS_SLIDE_NEG: ("slides, −μ side", "#b35a00", "down")}
FORCE_CLASSES = 5
"""Width classes of the force network, as the lab's: class k holds k/K <= |F|/max|F| < (k+1)/K."""
CYCLE_SHADES = [(157, 202, 225), (79, 155, 203), (25, 102, 173), (8, 48, 107)]
"""The q–γ path's colour from the first cycle (light) to the last (dark), as the lab's plot."""
MODEL_STYLES = [("#d62728", ""), ("#1f77b4", ""), ("#2ca02c", "8 5"), ("#9467bd", "8 5")]
"""Colour and dash of each tangential model, in the order of the registry, as in the lab's plots: the
angle spring's lies on the α-corrected one and LAMMPS's on Cundall–Strack's, so those are dashed."""
STRAIN_LABEL = "γ(N) − γ(N_ref)  (Eq. 2)"

LINE_PLOTS = {
    "energy": ("Energy budget", "time", "energy (paper units)",
               [("kinetic", "kinetic", "#0072b2"), ("stored", "stored in springs", "#009e73"),
                ("dissipated", "dissipated", "#d55e00"), ("balance", "balance (should stay 0)", "#000000")]),
    "coordination": ("Coordination number z = 2M/N", "time", "z (contacts per disk)", [("z", "z", "#1f77b4")]),
    "coordination-gilabert": ("Coordination number z", "time", "z (contacts per disk)", [("z", "z", "#1f77b4")]),
    "solid-fraction": ("Solid fraction Φ", "time", "Φ (disk area / box area)", [("phi", "Φ", "#1f77b4")]),
    "pressure": ("Pressure on the cell (Gilabert Eq. 3)", "time", "P (units of F₁/a)",
                 [("pressure", "P", "#1f77b4")]),
    "kinetic": ("Kinetic energy", "time", "kinetic energy (units of F₁ a)", [("kinetic", "kinetic", "#1f77b4")]),
    "clusters": ("Number of clusters", "time", "clusters", [("clusters", "clusters", "#1f77b4")]),
    "springs": ("Spring D_t of each tangential model (ratcheting Fig. 9)", "springs", "D_t (length, paper units)",
                [(f"dt_{m.key}", m.label, "") for m in TANGENTIAL.values()]),
    "block-load": ("Sideways load and the block's velocity", "block", "load / μF_n;  velocity (paper units)",
                   [("load_ratio", "load / μF_n", "#1f77b4"), ("velocity", "velocity", "#d62728")]),
}
"""The lab's plots that are lines of one series against time: title, series, y label and the lines
(column, legend, colour; "" takes the tangential model's style)."""
LOG_PLOTS = ("kinetic",)


def files(out: Path, stem: str, indices: list[int]) -> list[Path]:
    return [out]


def read_run(run: h5py.File, indices: list[int]) -> dict:
    """What the page needs of the run beyond its frames: parameters, the lab's protocol and series,
    the energy of each frame and the cycle records."""
    params = h5md.parameters(run)
    energy = {name: values[indices] for name, values in h5md.energy_series(run).items()} or None
    cycles = None
    if "observables/cycles/cycle" in run and run["observables/cycles/cycle"].shape[0]:
        cycles = {name: run[f"observables/cycles/{name}"][()] for name in ("cycle", "time", "length_x", "length_y")}
    scene = run["parameters/scene"][()] if "parameters/scene" in run else b""
    normals = [wall.normal for wall in h5md.run_walls(run)] if "walls_json" in params else []
    return {"parameters": params, "protocol": h5md.run_protocol(run),
            "normals": np.asarray(normals, dtype=float).reshape(-1, 2),
            "series": h5md.lab_series(run), "energy": energy, "cycles": cycles,
            "scene": scene.decode() if isinstance(scene, bytes) else str(scene),
            "version": str(run["h5md/creator"].attrs.get("version", "")) if "h5md/creator" in run else "",
            "name": Path(run.filename).name}


def write(frames, out: Path, stem: str, indices: list[int], run: dict) -> None:
    protocol = run["protocol"]
    preset = PRESETS.get(protocol.get("lab_preset")) if run["series"] else None
    kept = _Frames(len(indices), protocol, run["normals"])
    for position, frame in enumerate(frames):
        kept.add(position, indices[position], frame)
    plots, thinned = _plots(run, preset, kept)
    series_bytes = sum(len(json.dumps(plot)) for plot in plots)
    shown = [key for key in SETTING_WORDS if preset is None or key in preset.controls]
    frames_data = kept.finish(MAX_BYTES - series_bytes, shown)
    data = {"title": preset.title if preset else _scene_title(run["scene"], stem),
            "preset": preset.name if preset else "", "presetName": preset.menu_name if preset else "",
            "file": run["name"], "version": run["version"],
            "timeLabel": preset.time_label if preset else "t", "changes": protocol.get("changes", []),
            "plots": plots, "keyPlots": [p["id"] for p in plots if p["key"]],
            "palettes": _palettes(), "colors": _colors(), "watchedLabels": kept.watched_labels,
            "constants": _constants(run["parameters"]), "notes": _notes(kept, thinned, preset, len(indices)),
            **frames_data}
    text = json.dumps(data, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    # inside <script>, "</" would close it: JSON allows "<" written as \u003c
    out.write_text(PAGE.replace("%TITLE%", _escape(data["title"])).replace("%STYLE%", STYLE)
                   .replace("%DATA%", text.replace("<", "\\u003c")).replace("%SCRIPT%", DRAWING + SCRIPT),
                   encoding="utf-8")


def _constants(params: dict) -> list[list[str]]:
    """The law's stiffnesses and the time step (the lab's settings leave them out: they do not change)."""
    items = [[key, f"{name} = {setting_text(_number(params, f'contact.{key}'))}"]
             for key, name in (("normal_stiffness", "K_n"), ("tangential_stiffness", "K_t"))
             if f"contact.{key}" in params]
    if "dt" in params:
        items.append(["dt", f"time step dt = {_compact(_number(params, 'dt'))}"])
    return items


def _number(params: dict, key: str) -> float:
    value = params[key]
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value):
        raise h5md.RunFileError(f"the run file's parameter {key} is {value!r}; a finite number is needed")
    return float(value)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _scene_title(scene: str, stem: str) -> str:
    """A run's scene title (``title = ...`` of its TOML), else the file's name."""
    try:
        title = tomllib.loads(scene).get("title") if scene else None
    except tomllib.TOMLDecodeError:
        title = None
    return str(title) if title else f"Run {stem}"


def _array(values, dtype: str) -> dict:
    """An array as the page decodes it: little-endian bytes in base64."""
    raw = np.ascontiguousarray(values, dtype=np.dtype(dtype).newbyteorder("<"))
    return {"dtype": np.dtype(dtype).str[1:], "b64": base64.b64encode(raw.tobytes()).decode()}


def _finite(value, digits: int = 9):
    """A number for JSON: rounded to ``digits`` significant digits, None where not finite."""
    value = float(value)
    return float(f"{value:.{digits}g}") if math.isfinite(value) else None


def _hex(rgb) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb))


def _table(anchors, cyclic: bool) -> list[str]:
    """256 colours interpolating ``anchors`` (back to the first if ``cyclic``), as the lab's tables."""
    colors = np.asarray(anchors + anchors[:1] if cyclic else anchors, dtype=np.float64)
    samples = np.arange(256) / (256 if cyclic else 255)
    stops = np.linspace(0.0, 1.0, len(colors))
    table = np.round(np.stack([np.interp(samples, stops, colors[:, c]) for c in range(3)], axis=1))
    return [_hex(c) for c in table]


def _palettes() -> dict:
    return {"rotation": _table(ROTATION_ANCHORS, True), "pressure": _table(PRESSURE_ANCHORS, False),
            "coordination": [_hex(c) for c in COORDINATION_COLORS], "sliding": [_hex(c) for c in SLIDING_DISK_COLORS]}


def _colors() -> dict:
    return {"kinds": [[name, _hex(color)] for name, color in CONTACT_KINDS],
            "watched": [_hex(c) for c in WATCHED_COLORS], **{k: _hex(c) for k, c in LINE_COLORS.items()}}


def force_classes(force: np.ndarray) -> np.ndarray:
    """Class of each contact force, as the lab's: min(K - 1, floor(K |F| / max|F|)), 0 if all are 0."""
    top = float(force.max()) if len(force) else 0.0
    if top <= 0.0:
        return np.zeros(len(force), dtype=np.uint8)
    return np.minimum((force * (FORCE_CLASSES / top)).astype(np.int64), FORCE_CLASSES - 1).astype(np.uint8)


SETTING_WORDS = {"friction": "friction", "tangential_model": "tangential spring", "normal_model": "normal spring",
                 "damping_ratio": "damping",
                 "pressure": "pressure", "amplitude": "amplitude", "period": "period", "phase": "phase",
                 "rolling_friction": "rolling friction", "rolling_stiffness": "rolling stiffness",
                 "cohesion_force": "cohesion", "cohesion_range": "range", "particles": "disks N", "seed": "seed"}
"""The settings the page shows, in this order (μ and the spring first: what a class compares): those
of a lab run's preset (the ones its controls change), the contact law of another run."""
OFF = {key: (text, keys) for text, keys in (("no rolling resistance", ("rolling_friction", "rolling_stiffness")),
                                            ("no cohesion", ("cohesion_force", "cohesion_range"))) for key in keys}


def _settings_text(values: dict, keys) -> list[list[str]]:
    """[key, text] of each of ``keys`` in ``values`` (``friction``, ``friction μ = 0.2``); rolling
    resistance and cohesion in a word when they are off."""
    items = []
    for key in keys:
        off = OFF.get(key)
        if off is not None and all(float(values.get(k, 0.0) or 0.0) == 0.0 for k in off[1]):
            if key == off[1][0]:
                items.append([off[0], off[0]])
            continue
        if key in values:
            symbol = CONTROL_SYMBOLS.get(key, "")
            value = setting_text(values[key]) + ("°" if key == "phase" else "")
            name = SETTING_WORDS.get(key, key)
            items.append([key, f"{name}: {value}" if key.endswith("_model") else
                          f"{name} {symbol} = {value}" if symbol else f"{name} = {value}"])
    return items


def _friction(values: dict) -> tuple[float | None, float]:
    """(μ, F0) of settings or a law as stored, μ None for ∞ (JSON has no infinity)."""
    mu = values.get("friction", 0.0)
    mu = math.inf if mu == "inf" else float(mu)
    return (mu if math.isfinite(mu) else None), float(values.get("cohesion_force", 0.0) or 0.0)


class _Frames:
    """The frames kept for the page (every ``stride``-th of those exported, the stride doubled
    whenever they outgrow the budget, and the last), and the time, z and Φ of every frame."""

    def __init__(self, count: int, protocol: dict, normals: np.ndarray):
        self.count = count
        self.normals = normals
        self.stride = 1
        self.kept: dict[int, dict] = {}
        self.scalars = {"t": [], "step": [], "z": [], "phi": []}
        self.watched = [tuple(pair) for pair in protocol.get("watched", [])]
        self.watched_labels = list(protocol.get("watched_labels", []))
        self.groups = [tuple(group) for group in protocol.get("views", [])]
        self.settings: dict[str, int] = {}
        self.bytes = 0
        self.budget = MAX_BYTES * 3 // 4

    def add(self, position: int, index: int, frame) -> None:
        raw = frame.raw
        status, pair = frame.contacts["status"], frame.pair
        self.scalars["t"].append(raw["time"])
        self.scalars["step"].append(raw["step"])
        self.scalars["z"].append(coordination(status, pair[:, 0], pair[:, 1], frame.n))
        boxed = any(frame.periodic) or len(self.normals) >= 4
        self.scalars["phi"].append(solid_fraction(raw["radius"], frame.lengths) if boxed else math.nan)
        if position % self.stride and position != self.count - 1:
            return
        entry = self._entry(index, frame)
        if position == 0:
            # the first frame sets the stride the budget allows (contacts may grow: doubled below)
            self.stride = max(1, math.ceil(self.count * entry["bytes"] / self.budget))
        self.kept[position] = entry
        self.bytes += entry["bytes"]
        while self.bytes > self.budget and len(self.kept) > 2:
            self.stride *= 2
            for p in [p for p in self.kept if p % self.stride and p != position]:
                self.bytes -= self.kept.pop(p)["bytes"]

    def _entry(self, index: int, frame) -> dict:
        raw, scene = frame.raw, frame.scene
        n = frame.n
        pressure = scene.pressure
        top = float(pressure.max()) if n else 0.0
        codes = pair_codes(frame.pair[:, 0], frame.pair[:, 1])
        watched = np.full(len(codes), -1, dtype=np.int8)
        for k, (i, j) in enumerate(self.watched):
            watched[codes == pair_codes(min(i, j), max(i, j))] = k % 127
        settings = raw.get("lab_settings_json") or raw.get("law_json") or "{}"
        cell = [float(x) for x in scene.cell] if scene.cell is not None else None
        labels = group_labels(scene.positions, scene.radii, self.groups) if self.groups else ()
        entry = {"index": index, "time": float(raw["time"]), "step": int(raw["step"]),
                 "phase": str(raw.get("lab_phase", "")),
                 "settings": self.settings.setdefault(settings, len(self.settings)),
                 "cell": cell, "labels": [[text, _finite(x, 7), _finite(y, 7)] for text, x, y in labels],
                 "pos": scene.positions.astype(np.float32), "radius": scene.radii.astype(np.float32),
                 "angle": np.mod(scene.angles, 2.0 * np.pi).astype(np.float32),
                 "coord": np.minimum(scene.coordination, 255).astype(np.uint8),
                 "pidx": (np.rint(pressure * (255.0 / top)) if top > 0.0 else np.zeros(n)).astype(np.uint8),
                 "slide": scene.sliding.astype(np.uint8), "seg": scene.contacts.astype(np.float32),
                 "fclass": force_classes(scene.contact_force), "kind": scene.contact_kind.astype(np.uint8),
                 "watch": watched, "walls": _walls(raw, self.normals, scene).astype(np.float32)}
        entry["bytes"] = sum(v.nbytes for v in entry.values() if isinstance(v, np.ndarray)) + 200
        entry["bounds"] = _bounds(scene, entry["walls"], labels)
        return entry

    def finish(self, budget: int, shown: list[str]) -> dict:
        """The kept frames as the page's data (thinned further if the series left less room), with
        the settings ``shown`` of each."""
        self.budget = min(self.budget, max(0, budget) * 3 // 4)
        while self.bytes > self.budget and len(self.kept) > 2:
            self.stride *= 2
            last = max(self.kept)
            for p in [p for p in self.kept if p % self.stride and p != last]:
                self.bytes -= self.kept.pop(p)["bytes"]
        entries = [self.kept[p] for p in sorted(self.kept)]
        radius = entries[0]["radius"]
        constant = all(np.array_equal(e["radius"], radius) for e in entries)
        offsets = np.cumsum([0] + [len(e["seg"]) for e in entries])
        bounds = np.array([e["bounds"] for e in entries])
        settings = [json.loads(text) for text in sorted(self.settings, key=self.settings.get)]
        return {"frames": {"count": len(entries), "index": [e["index"] for e in entries],
                           "time": [e["time"] for e in entries], "step": [e["step"] for e in entries],
                           "phase": [e["phase"] for e in entries], "settings": [e["settings"] for e in entries],
                           "mu": [_friction(settings[e["settings"]])[0] for e in entries],
                           "f0": [_friction(settings[e["settings"]])[1] for e in entries],
                           "cell": [e["cell"] for e in entries], "labels": [e["labels"] for e in entries]},
                "settings": [_settings_text(s, shown) for s in settings],
                "disks": int(len(radius)), "walls": int(len(entries[0]["walls"])), "radiusPerFrame": not constant,
                "bounds": [float(bounds[:, 0].min()), float(bounds[:, 1].max()), float(bounds[:, 2].min()),
                           float(bounds[:, 3].max())],
                "frameBounds": bounds.round(7).tolist() if _travels(bounds) else None,
                "meanRadius": float(np.mean(radius)) if len(radius) else 1.0,
                "arrays": {"pos": _array(np.concatenate([e["pos"].ravel() for e in entries]), "f4"),
                           "radius": _array(np.concatenate([e["radius"] for e in entries]) if not constant else radius,
                                            "f4"),
                           **{name: _array(np.concatenate([e[name].ravel() for e in entries]), dtype)
                              for name, dtype in (("angle", "f4"), ("coord", "u1"), ("pidx", "u1"), ("slide", "u1"),
                                                  ("seg", "f4"), ("fclass", "u1"), ("kind", "u1"), ("watch", "i1"),
                                                  ("walls", "f4"))},
                           "coff": _array(offsets, "i4")}}


def _travels(bounds: np.ndarray) -> bool:
    """Whether the packing travels across a region much larger than itself (a block sliding along its
    floor): the scene then follows it frame by frame, else it keeps one framing for every frame."""
    sizes = np.maximum(bounds[:, 1] - bounds[:, 0], bounds[:, 3] - bounds[:, 2])
    union = max(bounds[:, 1].max() - bounds[:, 0].min(), bounds[:, 3].max() - bounds[:, 2].min())
    return bool(union > TRAVEL * np.median(sizes))


def _walls(raw: dict, normals: np.ndarray, scene) -> np.ndarray:
    """(W, 2, 2) each wall as a segment across the disks and the other walls, ending where they end
    (the lab's 3D scene draws them four radii past the disks: a box's walls then cross at its corners,
    and the packing is drawn smaller for it); NaN where a wall misses that region."""
    offsets = np.asarray(raw.get("wall_position", np.zeros(len(normals))), dtype=float)
    return meeting_walls(normals, offsets, scene.positions, scene.radii)


def _bounds(scene, walls: np.ndarray, labels) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the disks, the walls, the cell and the labels under groups of disks."""
    x = [scene.positions[:, 0] - scene.radii, scene.positions[:, 0] + scene.radii, walls[:, :, 0].ravel()]
    y = [scene.positions[:, 1] - scene.radii, scene.positions[:, 1] + scene.radii, walls[:, :, 1].ravel()]
    if scene.cell is not None:
        corners = cell_outline(scene.cell).reshape(-1, 2)
        x.append(corners[:, 0])
        y.append(corners[:, 1])
    x, y = np.concatenate(x), np.concatenate(y)
    if labels:
        y = np.append(y, min(label[2] for label in labels) - 1.5 * float(scene.radii.mean()))
    return float(np.nanmin(x)), float(np.nanmax(x)), float(np.nanmin(y)), float(np.nanmax(y))


def _layer(kind: str, x, y, t=None, color: str = "#1f77b4", dash: str = "", label: str = "") -> dict:
    """What a plot draws: a ``line`` or ``dots`` (``up``/``down`` triangles), coloured up to the
    frame shown and faint after it when it has times ``t``; ``x``, ``y``, ``t`` arrays."""
    layer = {"type": kind, "color": color, "dash": dash, "label": label,
             "x": np.asarray(x, dtype=float), "y": np.asarray(y, dtype=float)}
    if t is not None:
        layer["t"] = np.asarray(t, dtype=float)
    return layer


def _plot(plot_id: str, title: str, x_label: str, y_label: str, layers: list, legend: list, **options) -> dict:
    return {"id": plot_id, "title": title, "xLabel": x_label, "yLabel": y_label, "layers": layers,
            "legend": legend, "key": False, "timeX": False, "logY": False, "wholeX": False, "cone": None, "marks": [],
            **options}


def _plots(run: dict, preset, kept: _Frames) -> tuple[list[dict], list[str]]:
    """The preset's plots whose series the run holds (its key plots first), or the plots of every
    run; with the plots whose samples were thinned, for the page's notes."""
    series, protocol = run["series"], run["protocol"]
    plots = []
    if preset is not None:
        names = list(preset.key_plots) + [name for name in preset.plots if name not in preset.key_plots]
        for name in names:
            plot = _preset_plot(name, preset, series, protocol, kept)
            if plot is not None:
                plot["key"] = name in preset.key_plots
                plots.append(plot)
    else:
        plots = _frame_plots(run, kept)
        for plot in plots[:2]:
            plot["key"] = True
    thinned = []
    for plot in plots:
        count = sum(len(layer["x"]) for layer in plot["layers"])
        stride = max(1, math.ceil(count / PLOT_POINTS))
        if stride > 1:
            thinned.append(f"{plot['title']}: every {_ordinal(stride)} sample")
        for layer in plot["layers"]:
            keep = np.unique(np.append(np.arange(0, len(layer["x"]), stride), len(layer["x"]) - 1)) \
                if len(layer["x"]) else np.zeros(0, dtype=int)
            for key in ("x", "y", "t"):
                if key in layer:
                    layer[key] = _array(layer[key][keep], "f8" if key == "t" else "f4")
    return plots, thinned


def _ordinal(k: int) -> str:
    return f"{k}{'th' if 10 <= k % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(k % 10, 'th')}"


def _columns(series: dict, name: str) -> dict | None:
    if name not in series or not len(series[name][1]):
        return None
    columns, rows = series[name]
    return {column: rows[:, k] for k, column in enumerate(columns)}


def _time_marks(protocol: dict) -> list[dict]:
    return [{"x": change["t"], "text": change["text"]} for change in protocol.get("changes", [])]


def _preset_plot(name: str, preset, series: dict, protocol: dict, kept: _Frames) -> dict | None:
    time_label = preset.time_label
    if name in LINE_PLOTS:
        title, source, y_label, lines = LINE_PLOTS[name]
        c = _columns(series, source)
        if c is None:
            return None
        styles = iter(MODEL_STYLES)
        layers = []
        for column, label, color in lines:
            if column in c:
                color, dash = (color, "") if color else next(styles)
                layers.append(_layer("line", c["t"], c[column], c["t"], color, dash, label))
        if not layers:
            return None
        plot = _plot(name, title, time_label, y_label, layers, [_legend_line(layer) for layer in layers],
                     timeX=True, logY=name in LOG_PLOTS, marks=_time_marks(protocol))
        if name == "block-load":
            t = c["t"][[0, -1]]
            plot["layers"].append(_layer("line", t, [1.0, 1.0], None, "#555555", "2 4", "μF_n: sliding can start"))
            plot["legend"].append(_legend_line(plot["layers"][-1]))
        return plot
    if name == "strain-per-cycle":
        c = _columns(series, "cycles")
        return None if c is None else _strain_plot(c["cycle"], c["gamma"], c["t"], preset.reference_cycle, protocol)
    if name == "q-gamma":
        c = _columns(series, "time")
        return None if c is None or "q" not in c else _load_strain_plot(c)
    if name in ("coulomb-cone", "block-cone"):
        c = _columns(series, "contacts" if name == "coulomb-cone" else "block")
        if c is None:
            return None
        title = "Watched contacts, Coulomb cone" if name == "coulomb-cone" else \
            "The block's contact, Coulomb cone (Fig. 3)"
        return _cone_plot(name, title, c, kept)
    if name == "spring-path":
        c = _columns(series, "springs")
        if c is None:
            return None
        layers = [_layer("line", c[f"dt_{m.key}"], c[f"dn_{m.key}"], c["t"], color, dash, m.label)
                  for m, (color, dash) in zip(TANGENTIAL.values(), MODEL_STYLES) if f"dn_{m.key}" in c]
        return _plot(name, "(D_t, D_n) along the closed path A→B→C→D→A", "D_t (length, paper units)",
                     "D_n (gap, < 0: overlap)", layers, [_legend_line(layer) for layer in layers])
    return None


def _legend_line(layer: dict) -> dict:
    return {"label": layer["label"], "color": layer["color"], "shape": "dash" if layer["dash"] else "line"}


def _strain_plot(cycle, gamma, t, reference: int, protocol: dict) -> dict:
    """Ratcheting Fig. 2: γ at the start of each cycle from the reference cycle on (grey before the
    cycle the fit starts from: after the last change of the physics), the strain per cycle fitted."""
    marks = [{"x": c["cycle"], "text": c["text"]} for c in protocol.get("changes", []) if c.get("cycle") is not None]
    start = math.ceil(marks[-1]["x"] - 1e-9) + reference if marks else reference
    first = min(reference, start)
    pairs = list(zip(cycle.astype(int).tolist(), gamma.tolist()))
    known = dict(pairs)
    plot = _plot("strain-per-cycle", "Strain at the start of each cycle", "cycle N", STRAIN_LABEL, [], [],
                 marks=marks, wholeX=True)
    if first not in known:
        plot["title"] = f"Strain per cycle, from cycle {first} (the run ends before it)"
        return plot
    origin = known[start] if start in known else known[first]
    shown = cycle >= first
    before, fitted = shown & (cycle < start), cycle >= start
    strain = gamma - origin
    if before.any():
        plot["layers"].append(_layer("dots", cycle[before], strain[before], t[before], "#9a9a9a", "",
                                     "settling: not fitted"))
    plot["layers"].append(_layer("dots", cycle[fitted], strain[fitted], t[fitted], "#1f77b4", "",
                                 "γ at a cycle start"))
    fit = strain_fit(pairs, start)
    if fit is None:
        plot["title"] = f"Strain per cycle: the fit from cycle {start} needs 3 cycles"
    else:
        ends = np.array([start, cycle.max()], dtype=float)
        line = fit["mean_gamma"] - origin + fit["dgamma"] * (ends - fit["mean_cycle"])
        verdict = "ratcheting" if fit["ratcheting"] else "no clear ratcheting"
        plot["title"] = f"Δγ = {_compact(fit['dgamma'])} per cycle from cycle {start}: {verdict}"
        plot["layers"].append(_layer("line", ends, line, None, "#d62728", "",
                                     "fit" + ("" if fit["ratcheting"] else " (scatter > drift)")))
    plot["legend"] = [{"label": layer["label"], "color": layer["color"],
                       "shape": "dot" if layer["type"] == "dots" else "line"} for layer in plot["layers"]]
    return plot


def _compact(value: float) -> str:
    """A number as the lab's titles show it: ``5.06×10⁻⁸``."""
    if value == 0 or 1e-3 <= abs(value) < 1e5:
        return f"{value:.4g}".replace("-", "−")
    mantissa, exponent = f"{value:.2e}".split("e")
    return f"{float(mantissa):g}".replace("-", "−") + "×10" + str(int(exponent)).translate(
        str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))


def _load_strain_plot(c: dict) -> dict:
    """Ratcheting Fig. 1: q against γ while cycling, each cycle a shade of blue darker than the one before."""
    cycling = c["cycle"] >= 0
    cycles = np.unique(c["cycle"][cycling]).astype(int)
    layers = []
    shades = np.asarray(CYCLE_SHADES, dtype=float)
    for k, number in enumerate(cycles):
        rows = np.flatnonzero(c["cycle"] == number)
        if k + 1 < len(cycles):  # the path goes on without a gap into the next cycle
            rows = np.append(rows, rows[-1] + 1)
        where = k / max(1, len(cycles) - 1) * (len(shades) - 1)
        color = [np.interp(where, np.arange(len(shades)), shades[:, i]) for i in range(3)]
        layers.append(_layer("line", c["gamma"][rows], c["q"][rows], c["t"][rows], _hex(np.round(color))))
    legend = [{"label": "cycle", "shape": "gradient", "colors": [_hex(s) for s in CYCLE_SHADES],
               "ends": [str(cycles[0]), str(cycles[-1])] if len(cycles) else ["", ""]}]
    return _plot("q-gamma", "Load q against strain γ (ratcheting Fig. 1)", "γ = L_y/L_y0 − L_x/L_x0  (Eq. 2)",
                 "q  (Eq. 1, units of P0)", layers, legend)


def _cone_plot(name: str, title: str, c: dict, kept: _Frames) -> dict:
    """Watched contacts in the (F_n, F_t) plane, each in its colour in the scene, sliding samples
    marked by side, and the Coulomb cone |F_t| = μ(F_n + F0) at the friction of the frame shown."""
    watched = kept.watched
    if "i" in c:
        pairs = np.column_stack([c["i"], c["j"]]).astype(np.int64)
    else:
        pairs = np.tile(watched[0] if watched else (0, 1), (len(c["t"]), 1))
    labels = dict(zip(watched, kept.watched_labels))
    layers, legend = [], []
    for pair in sorted({tuple(p) for p in pairs.tolist()}, key=lambda p: (watched.index(p) if p in watched
                                                                          else len(watched), p)):
        rows = np.flatnonzero((pairs[:, 0] == pair[0]) & (pairs[:, 1] == pair[1]))
        k = watched.index(pair) if pair in watched else len(watched)
        color = _hex(WATCHED_COLORS[k % len(WATCHED_COLORS)])
        label = labels.get(pair, "%d–%d" % pair)
        layers.append(_layer("line", c["normal"][rows], c["tangential"][rows], c["t"][rows], color, "", label))
        legend.append({"label": label, "color": color, "shape": "line"})
    status = c["status"].astype(int)
    for code, (label, color, shape) in STATUS_MARKS.items():
        rows = np.flatnonzero(status == code)
        if len(rows):
            layers.append(_layer(shape, c["normal"][rows], c["tangential"][rows], c["t"][rows], color, "", label))
            legend.append({"label": label, "color": color, "shape": shape})
    legend.insert(0, {"label": "|F_t| = μ(F_n+F0)", "color": "#333333", "shape": "dash"})
    top = 1.1 * float(np.abs(c["normal"]).max()) if len(c["normal"]) else 1.0
    return _plot(name, title, "F_n = Nᵉ − F0  (elastic normal force)", "F_t  (tangential force)", layers, legend,
                 cone={"top": top})


def _frame_plots(run: dict, kept: _Frames) -> list[dict]:
    """A run without the lab's series: its energy budget, z and Φ frame by frame, and the strain per
    cycle if it was cycled."""
    s = {k: np.asarray(v, dtype=float) for k, v in kept.scalars.items()}
    t = s["t"]
    plots = []
    if run["cycles"] is not None and len(run["cycles"]["cycle"]) >= 2:
        cyc = run["cycles"]
        gamma = cyc["length_y"] / cyc["length_y"][0] - cyc["length_x"] / cyc["length_x"][0]
        plots.append(_strain_plot(cyc["cycle"].astype(float), gamma, cyc["time"], int(cyc["cycle"][0]), {}))
    if run["energy"] is not None:
        lines = LINE_PLOTS["energy"][3]
        layers = [_layer("line", t, run["energy"][col], t, color, "", label) for col, label, color in lines]
        plots.append(_plot("energy", "Energy budget, frame by frame", "t", "energy (paper units)", layers,
                           [_legend_line(layer) for layer in layers], timeX=True))
    layers = [_layer("line", t, s["z"], t, "#1f77b4", "", "z")]
    plots.append(_plot("coordination", "Coordination number z = 2M/N, frame by frame", "t", "z (contacts per disk)",
                       layers, [_legend_line(layers[0])], timeX=True))
    if np.isfinite(s["phi"]).all():
        layers = [_layer("line", t, s["phi"], t, "#1f77b4", "", "Φ")]
        plots.append(_plot("solid-fraction", "Solid fraction Φ, frame by frame", "t", "Φ (disk area / box area)",
                           layers, [_legend_line(layers[0])], timeX=True))
    return plots


def _notes(kept: _Frames, thinned: list[str], preset, exported: int) -> list[str]:
    count = len(kept.kept)
    notes = []
    if count < exported:
        notes.append(f"To keep this page under 10 MB it holds {count} of the {exported} frames exported "
                     f"(every {_ordinal(kept.stride)}, and the last); the plots hold every frame's values.")
    notes += [f"Thinned to keep the page small: {text}." for text in thinned]
    if preset is None:
        notes.append("This run was not saved by the lab: its plots are what every run file holds "
                     "(the energy budget, z and Φ of each frame, the strain of each load cycle).")
    notes.append("Coordinates are stored as 32-bit floats (7 significant digits).")
    return notes


PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="GranLab export --format html">
<title>%TITLE%</title>
<style>%STYLE%</style>
</head>
<body>
<header>
  <h1 id="title"></h1>
  <div id="subtitle"></div>
  <div id="settings" title="the settings in effect at the frame shown"></div>
</header>
<main id="main">
  <section id="scene-pane">
    <div class="tools">
      <label>disk colour <select id="color-field">
        <option value="rotation">rotation θ</option><option value="coordination">contacts z</option>
        <option value="pressure">pressure</option><option value="sliding">sliding contact</option>
      </select></label>
      <label><input type="checkbox" id="forces" checked> force network</label>
      <span id="phase"></span>
    </div>
    <div id="scene-box"><canvas id="scene" aria-label="the packing at the frame shown"></canvas></div>
    <div id="legend"></div>
  </section>
  <section id="key-plots"></section>
</main>
<section id="more">
  <h2 id="other-title">More plots of this run</h2>
  <div id="other-plots"></div>
  <div id="changes"></div>
  <h2>About this page</h2>
  <ul id="notes"></ul>
</section>
<footer id="timeline">
  <button id="play" type="button" title="play or pause (space)">▶ Play</button>
  <input type="range" id="frame" min="0" max="0" step="1" value="0" aria-label="frame">
  <span id="frame-label"></span>
  <label>speed <select id="fps"><option value="4">slow</option><option value="10" selected>normal</option>
    <option value="25">fast</option></select></label>
</footer>
<script type="application/json" id="handout-data">%DATA%</script>
<script>%SCRIPT%</script>
</body>
</html>
"""

STYLE = """
* { box-sizing: border-box; }
html, body { margin: 0; padding: 0; }
body { font-family: "DejaVu Sans", "Segoe UI", Arial, Helvetica, sans-serif; font-size: 15px; color: #1a1a1a;
       background: #ffffff; }
header { padding: 6px 14px 4px; border-bottom: 1px solid #d0d0d0; }
h1 { font-size: 21px; margin: 0 0 2px; }
h2 { font-size: 17px; margin: 14px 0 6px; }
#subtitle { font-size: 14px; color: #444444; }
#settings { font-size: 14px; margin-top: 2px; }
#settings span { display: inline-block; margin-right: 14px; white-space: nowrap; }
#settings .changed { background: #f3e5f5; color: #7b1fa2; border-radius: 3px; padding: 0 3px; }
main { display: grid; grid-template-columns: minmax(0, 46fr) minmax(0, 54fr); grid-template-rows: minmax(0, 1fr);
       gap: 8px; padding: 4px 10px 0; }
#scene-pane { display: flex; flex-direction: column; min-height: 0; overflow: hidden; }
.tools { font-size: 14px; display: flex; gap: 14px; align-items: center; flex-wrap: wrap; }
select, button, input { font-size: 14px; }
#phase { font-weight: bold; }
#scene-box { flex: 1; min-height: 0; position: relative; }
#scene { position: absolute; left: 0; top: 0; width: 100%; height: 100%; }
#legend { font-size: 13px; line-height: 1.55; }
.sw { display: inline-flex; align-items: center; margin-right: 10px; white-space: nowrap; }
.sw i { display: inline-block; margin-right: 4px; }
.sw .dot { width: 12px; height: 12px; border-radius: 50%; border: 1px solid #464646; }
.sw .ln { width: 20px; height: 4px; border-radius: 2px; }
.sw .grad { width: 90px; height: 11px; margin: 0 4px; border: 1px solid #464646; }
#key-plots { display: flex; flex-direction: column; min-height: 0; gap: 6px; overflow: hidden; }
#key-plots .plot { flex: 1; min-height: 0; }
#other-plots { display: grid; grid-template-columns: 1fr 1fr; gap: 8px; }
#other-plots .plot { height: 330px; }
.plot { display: flex; flex-direction: column; border: 1px solid #e2e2e2; border-radius: 4px; padding: 2px 4px; }
.plot-title { font-size: 15px; font-weight: bold; margin: 1px 2px; }
.plot-body { flex: 1; min-height: 0; display: flex; }
.plot-area { flex: 1; min-width: 0; position: relative; }
.plot-area svg { position: absolute; left: 0; top: 0; width: 100%; height: 100%; }
.plot-legend { font-size: 13px; padding: 4px 2px 0 6px; max-width: 36%; overflow: hidden; }
.plot-legend div { display: flex; align-items: center; margin-bottom: 3px; }
.plot-legend i { display: inline-block; flex: none; margin-right: 5px; }
#more { padding: 0 12px 70px; }
#more ul { font-size: 14px; }
#changes { font-size: 14px; }
#timeline { position: sticky; bottom: 0; display: flex; align-items: center; gap: 12px; padding: 6px 14px;
            background: #f4f4f4; border-top: 1px solid #cfcfcf; font-size: 15px; }
#frame { flex: 1; min-width: 120px; height: 22px; }
#play { min-width: 92px; padding: 3px 8px; }
#frame-label { white-space: nowrap; font-variant-numeric: tabular-nums; }
svg text { font-family: inherit; fill: #1a1a1a; }
"""

DRAWING = (Path(__file__).parent / "packing.js").read_text(encoding="utf-8")
"""The drawing of a packing the handout shares with the viewers' scene of the lab (``drawPacking``)."""

SCRIPT = r"""
"use strict";
const D = JSON.parse(document.getElementById("handout-data").textContent);
const TYPES = {f4: Float32Array, f8: Float64Array, u1: Uint8Array, i1: Int8Array, i4: Int32Array};
function decode(a) {
  const text = atob(a.b64), bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  return new TYPES[a.dtype](bytes.buffer);
}
const A = {};
for (const name in D.arrays) A[name] = decode(D.arrays[name]);
const F = D.frames, N = D.disks, W = D.walls, COUNT = F.count;
const $ = id => document.getElementById(id);
const SVGNS = "http://www.w3.org/2000/svg";
let frame = 0, colorField = "rotation", showForces = true, timer = null;

const SUP = {"-": "⁻", "0": "⁰", "1": "¹", "2": "²", "3": "³", "4": "⁴", "5": "⁵", "6": "⁶", "7": "⁷", "8": "⁸",
             "9": "⁹"};
function compact(v) {  // as the lab's axes: plain from 10⁻³ to 10⁵, else m×10ⁿ
  if (v === 0) return "0";
  const a = Math.abs(v);
  if (a >= 1e-3 && a < 1e5) return String(Number(v.toPrecision(4))).replace("-", "−");
  const parts = v.toExponential(2).split("e");
  const m = String(Number(parts[0])).replace("-", "−");
  const e = String(Number(parts[1])).split("").map(c => SUP[c] || c).join("");
  return (m === "1" ? "" : m === "−1" ? "−" : m + "×") + "10" + e;
}
function timeText(t) {  // four significant digits, never an exponent
  const digits = Math.max(4, Math.ceil(Math.log10(Math.abs(t) + 1)));
  return String(Number(t.toPrecision(digits))).replace("-", "−");
}
function esc(text) {
  return String(text).replace(/&/g, "&amp;").replace(/</g, "&lt;").replace(/>/g, "&gt;").replace(/"/g, "&quot;");
}
function node(name, attrs, parent, svg) {
  const e = svg ? document.createElementNS(SVGNS, name) : document.createElement(name);
  for (const k in attrs) e.setAttribute(k, attrs[k]);
  if (parent) parent.appendChild(e);
  return e;
}

// ---- the header
$("title").textContent = D.title;
const timeName = D.timeLabel.split(" ")[0];
$("subtitle").textContent = [D.preset ? `lab preset ${D.preset}: ${D.presetName}` : "", `run file ${D.file}`,
  N === 1 ? "1 disk" : `${N} disks`,
  `${COUNT} frames, ${timeName} from ${timeText(F.time[0])} to ${timeText(F.time[COUNT - 1])}`,
  `time ${D.timeLabel}`, D.version ? `made with GranLab ${D.version}` : ""].filter(Boolean).join(" · ");
function showSettings() {
  const first = new Map(D.settings[F.settings[0]] || []), box = $("settings");
  box.textContent = "";
  for (const [key, text] of (D.settings[F.settings[frame]] || []).concat(D.constants)) {
    const span = node("span", {}, box);
    span.textContent = text;
    if (first.has(key) && first.get(key) !== text) {
      span.className = "changed";
      span.title = `at the first frame: ${first.get(key)}`;
    }
  }
}

// ---- the scene
const canvas = $("scene"), ctx = canvas.getContext("2d");
function diskColor(k, i) {
  const at = k * N + i, P = D.palettes;
  if (colorField === "rotation") return P.rotation[Math.floor(A.angle[at] * 256 / (2 * Math.PI)) & 255];
  if (colorField === "coordination") return P.coordination[Math.min(A.coord[at], P.coordination.length - 1)];
  if (colorField === "pressure") return P.pressure[A.pidx[at]];
  return P.sliding[A.slide[at]];
}
function drawScene() {
  const box = $("scene-box"), w = box.clientWidth, h = box.clientHeight;
  fitCanvas(canvas, ctx, w, h);
  const k = frame, base = D.radiusPerFrame ? k * N : 0, C = D.colors, P = A.pos, S = A.seg;
  const c0 = A.coff[k], c1 = A.coff[k + 1], watched = [];
  for (let m = c0; m < c1; m++) {
    if (A.watch[m] >= 0) watched.push([S[4 * m], S[4 * m + 1], S[4 * m + 2], S[4 * m + 3],
                                       C.watched[A.watch[m] % C.watched.length]]);
  }
  drawPacking(ctx, {
    width: w, height: h, bounds: D.frameBounds ? D.frameBounds[k] : D.bounds, meanRadius: D.meanRadius,
    n: N, x: i => P[2 * (k * N + i)], y: i => P[2 * (k * N + i) + 1], radius: i => A.radius[base + i],
    angle: i => A.angle[k * N + i], fill: i => diskColor(k, i), edge: C.edge,
    forces: showForces && {count: c1 - c0, segment: c => S.subarray(4 * (c0 + c), 4 * (c0 + c) + 4),
                           level: c => A.fclass[c0 + c], kind: c => A.kind[c0 + c], levels: 5, width: 0.4,
                           kindColors: C.kinds.map(kind => kind[1])},
    watched, watchedWidth: 0.3, spoke: C.spoke, wall: C.wall, walls: A.walls.subarray(4 * k * W, 4 * (k + 1) * W),
    cell: F.cell[k], cellColor: C.cell, arrows: [], labels: F.labels[k]});
  canvas.dataset.frame = String(k);
}

function swatch(color, text, shape) {
  return `<span class="sw"><i class="${shape}" style="background:${color}"></i>${esc(text)}</span>`;
}
function gradient(colors, left, right) {
  const stops = colors.filter((c, i) => i % Math.max(1, Math.floor(colors.length / 12)) === 0).join(", ");
  return `<span class="sw">${esc(left)}<i class="grad" style="background:linear-gradient(to right, ${stops})"></i>` +
    `${esc(right)}</span>`;
}
const KINDS_SEEN = new Set(A.kind), COHESIVE = F.f0.some(f => f > 0);
const WATCHED_SEEN = new Set(Array.from(A.watch).filter(w => w >= 0));
function drawLegend() {
  const P = D.palettes, C = D.colors, rows = [];
  const disks = {
    rotation: () => "disk colour = rotation angle θ: " + gradient(P.rotation, "0", "2π (cyclic)"),
    coordination: () => "disk colour = contacts z: " + P.coordination.map((c, z) =>
      swatch(c, z === 0 ? "0 (rattler)" : z === P.coordination.length - 1 ? `${z} or more` : String(z), "dot"))
      .join(""),
    pressure: () => "disk colour = pressure on the disk: " + gradient(P.pressure, "0", "the frame's largest"),
    sliding: () => "disk colour: " + swatch(P.sliding[0], "no sliding contact", "dot") +
      swatch(P.sliding[1], "a contact sliding", "dot"),
  };
  rows.push(disks[colorField]() + swatch(C.spoke, "spoke: the disk's angle θ", "ln"));
  const boundary = (W ? swatch(C.wall, "walls", "ln") : "") +
    (F.cell.some(c => c) ? swatch(C.cell, "periodic cell (dashed)", "ln") : "");
  if (showForces) {
    // the kinds the run has (compressive always); a pull without cohesion is the damping's
    const kinds = C.kinds.map(([name, color], code) => code === 0 || KINDS_SEEN.has(code) ?
      swatch(color, code === 1 && !COHESIVE ? "tensile (damping)" : name, "ln") : "");
    rows.push("force network: " + kinds.join("") + '<span class="sw">line width ∝ |F|</span>' + boundary);
  } else if (boundary) {
    rows.push(boundary);
  }
  const watched = D.watchedLabels
    .map((label, k) => WATCHED_SEEN.has(k) ? swatch(C.watched[k % C.watched.length], label, "ln") : "")
    .join("");
  if (watched) rows.push("watched contacts (colours of the cone plot): " + watched);
  $("legend").innerHTML = rows.map(r => `<div>${r}</div>`).join("");
}

// ---- the plots
function niceTicks(lo, hi, count, whole) {  // whole: no tick between two whole numbers (a cycle count)
  const raw = (hi - lo) / Math.max(1, count), mag = Math.pow(10, Math.floor(Math.log10(raw))), r = raw / mag;
  const nice = (r >= 7.5 ? 10 : r >= 3.5 ? 5 : r >= 1.5 ? 2 : 1) * mag, out = [];
  const step = whole ? Math.max(1, nice) : nice;
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) {
    out.push(Math.abs(v) < 1e-9 * step ? 0 : v);
  }
  return out;
}
function upper(t, now) {  // how many samples have t <= now
  let lo = 0, hi = t.length;
  while (lo < hi) { const mid = (lo + hi) >> 1; if (t[mid] <= now) lo = mid + 1; else hi = mid; }
  return lo;
}
function frameMu(k) {
  return F.mu[k] === null ? Infinity : F.mu[k];
}
class Plot {
  constructor(spec, parent) {
    this.spec = spec;
    const box = node("div", {"class": "plot", "data-plot": spec.id}, parent);
    this.title = node("div", {"class": "plot-title"}, box);
    this.title.textContent = spec.title;
    const body = node("div", {"class": "plot-body"}, box);
    const area = node("div", {"class": "plot-area"}, body);
    this.svg = node("svg", {"role": "img"}, area, true);
    new ResizeObserver(() => this.layout()).observe(area);
    const legend = node("div", {"class": "plot-legend"}, body);
    for (const item of spec.legend) {
      const row = node("div", {}, legend);
      let mark;
      if (item.shape === "gradient") {
        mark = `${esc(item.ends[0])}<i style="width:60px;height:11px;margin:0 4px;` +
          `background:linear-gradient(to right, ${item.colors.join(", ")})"></i>${esc(item.ends[1])}`;
        row.innerHTML = `${esc(item.label)}&nbsp;${mark}`;
        continue;
      }
      if (item.shape === "line") mark = `<i style="width:20px;height:3px;background:${item.color}"></i>`;
      else if (item.shape === "dash") mark = `<i style="width:20px;height:0;border-top:3px dashed ${item.color}"></i>`;
      else if (item.shape === "dot") {
        mark = `<i style="width:11px;height:11px;border-radius:50%;background:${item.color}"></i>`;
      }
      else mark = `<i style="width:0;height:0;border-left:6px solid transparent;border-right:6px solid transparent;` +
        `border-${item.shape === "up" ? "bottom" : "top"}:11px solid ${item.color}"></i>`;
      row.innerHTML = mark + esc(item.label);
    }
    this.layers = spec.layers.map(l => ({...l, x: decode(l.x), y: decode(l.y), t: l.t ? decode(l.t) : null}));
    this.range();
  }
  range() {
    const s = this.spec, fy = s.logY ? (v => v > 0 ? Math.log10(v) : NaN) : (v => v);
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const l of this.layers) {
      for (let i = 0; i < l.x.length; i++) {
        const y = fy(l.y[i]);
        if (!isFinite(l.x[i]) || !isFinite(y)) continue;
        x0 = Math.min(x0, l.x[i]); x1 = Math.max(x1, l.x[i]); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
      }
    }
    if (s.cone) {
      const mus = F.mu.filter(m => m !== null), mu = mus.length ? Math.max(...mus) : 0, f0 = Math.max(...F.f0);
      x0 = Math.min(x0, -f0); x1 = Math.max(x1, s.cone.top);
      y0 = Math.min(y0, -mu * (s.cone.top + f0)); y1 = Math.max(y1, mu * (s.cone.top + f0));
    }
    if (s.timeX) { x0 = Math.min(x0, F.time[0]); x1 = Math.max(x1, F.time[COUNT - 1]); }
    if (!isFinite(x0)) { x0 = 0; x1 = 1; y0 = 0; y1 = 1; }
    const padX = x1 > x0 ? 0.03 * (x1 - x0) : Math.max(Math.abs(x0), 1) * 0.5;
    const padY = y1 > y0 ? 0.06 * (y1 - y0) : Math.max(Math.abs(y0), 1e-12) * 0.5;
    this.xr = [x0 - padX, x1 + padX];
    this.yr = [y0 - padY, y1 + padY];
    this.fy = fy;
  }
  layout() {
    const svg = this.svg, s = this.spec, r = svg.getBoundingClientRect();
    svg.textContent = "";
    if (r.width < 40 || r.height < 40) return;
    const T = 8, B = 46, R = 10, w = r.width, h = r.height;
    const decades = [];
    for (let e = Math.ceil(this.yr[0]); e <= this.yr[1]; e++) decades.push(Math.pow(10, e));
    const yTicks = s.logY ? decades : niceTicks(this.yr[0], this.yr[1], Math.max(2, Math.floor((h - T - B) / 42)));
    const L = 34 + 7.6 * Math.max(...yTicks.map(v => compact(v).length));  // the y label beside the widest tick label
    if (w - L - R < 40) return;  // no room yet: laid out again once the page has its size
    const sx = v => L + (v - this.xr[0]) / (this.xr[1] - this.xr[0]) * (w - L - R);
    const sy = v => h - B - (this.fy(v) - this.yr[0]) / (this.yr[1] - this.yr[0]) * (h - T - B);
    this.sx = sx; this.sy = sy;
    const axes = node("g", {"font-size": "13"}, svg, true);
    for (const v of niceTicks(this.xr[0], this.xr[1], Math.max(2, Math.floor((w - L) / 95)), s.wholeX)) {
      node("line", {x1: sx(v), x2: sx(v), y1: T, y2: h - B, stroke: "#e6e6e6"}, axes, true);
      node("text", {x: sx(v), y: h - B + 17, "text-anchor": "middle"}, axes, true).textContent = compact(v);
    }
    for (const v of yTicks) {
      node("line", {x1: L, x2: w - R, y1: sy(v), y2: sy(v), stroke: "#e6e6e6"}, axes, true);
      node("text", {x: L - 5, y: sy(v) + 4, "text-anchor": "end"}, axes, true).textContent = compact(v);
    }
    node("rect", {x: L, y: T, width: w - L - R, height: h - T - B, fill: "none", stroke: "#888888"}, axes, true);
    node("text", {x: L + (w - L - R) / 2, y: h - 7, "text-anchor": "middle", "font-size": "14"}, axes, true)
      .textContent = s.xLabel;
    node("text", {x: 0, y: 0, "text-anchor": "middle", "font-size": "14",
                  transform: `translate(15 ${T + (h - T - B) / 2}) rotate(-90)`}, axes, true).textContent = s.yLabel;
    const clip = `clip-${s.id}`;
    node("rect", {x: L, y: T, width: w - L - R, height: h - T - B}, node("clipPath", {id: clip}, svg, true), true);
    const area = node("g", {"clip-path": `url(#${clip})`}, svg, true);
    for (const m of s.marks) {
      const x = sx(m.x);
      node("line", {x1: x, x2: x, y1: T, y2: h - B, stroke: "#7b1fa2", "stroke-dasharray": "6 4",
                    "stroke-width": 1.5}, area, true);
      node("text", {x: 0, y: 0, fill: "#7b1fa2", "font-size": "13",
                    transform: `translate(${x - 4} ${h - B - 4}) rotate(-90)`}, area, true).textContent = m.text;
    }
    if (s.cone) {
      this.cone = node("path", {fill: "none", stroke: "#333333", "stroke-dasharray": "7 5", "stroke-width": 1.5},
                       area, true);
    }
    this.now = s.timeX ? node("line", {y1: T, y2: h - B, stroke: "#555555", "stroke-width": 1}, area, true) : null;
    for (const l of this.layers) {
      const dots = l.type !== "line", cmds = [];
      let open = false;
      for (let i = 0; i < l.x.length; i++) {
        const X = sx(l.x[i]), Y = sy(l.y[i]);
        if (!isFinite(X) || !isFinite(Y)) { open = false; cmds.push(""); continue; }
        const x = X.toFixed(1), y = Y.toFixed(1);
        if (l.type === "dots") cmds.push(`M${(X - 3.5).toFixed(1)} ${y}a3.5 3.5 0 1 0 7 0a3.5 3.5 0 1 0 -7 0`);
        else if (l.type === "up") cmds.push(`M${x} ${(Y - 5).toFixed(1)}l5 9h-10z`);
        else if (l.type === "down") cmds.push(`M${x} ${(Y + 5).toFixed(1)}l5 -9h-10z`);
        else { cmds.push((open ? "L" : "M") + x + " " + y); open = true; }
      }
      l.cmds = cmds;
      const paint = dots ? {fill: l.color, stroke: "none"} :
        {fill: "none", stroke: l.color, "stroke-width": 2, "stroke-linejoin": "round",
         "stroke-dasharray": l.dash || "none"};
      if (l.t) {
        node("path", {...paint, d: cmds.join(""), opacity: 0.22}, area, true);
        l.past = node("path", {...paint, "class": "past"}, area, true);
        l.marker = node("circle", {r: 5.5, fill: l.color, stroke: "#000000", "stroke-width": 1.5, "class": "marker",
                                   visibility: "hidden"}, svg, true);
      } else {
        node("path", {...paint, d: cmds.join("")}, area, true);
      }
      l.shown = -1;
    }
    this.update(true);
  }
  update(force) {
    if (!this.sx) return;  // not laid out yet: layout() updates it
    const s = this.spec, now = F.time[frame] + 1e-9 * Math.max(1, Math.abs(F.time[frame]));
    let title = s.title;
    if (s.cone && this.cone) {
      const mu = frameMu(frame), f0 = F.f0[frame], top = s.cone.top;
      title += isFinite(mu) ? ` — μ = ${compact(mu)}` : " — μ = ∞, no cone";
      this.cone.setAttribute("d", isFinite(mu) ? `M${this.sx(top)} ${this.sy(mu * (top + f0))}L${this.sx(-f0)} ` +
        `${this.sy(0)}L${this.sx(top)} ${this.sy(-mu * (top + f0))}` : "");
    }
    this.title.textContent = title;
    if (this.now) { const x = this.sx(F.time[frame]); this.now.setAttribute("x1", x); this.now.setAttribute("x2", x); }
    for (const l of this.layers) {
      if (!l.t || !l.past) continue;
      const k = upper(l.t, now);
      if (k === l.shown && !force) continue;
      l.shown = k;
      l.past.setAttribute("d", l.cmds.slice(0, k).join(""));
      let last = k - 1;
      while (last >= 0 && !l.cmds[last]) last--;
      if (last < 0 || l.type !== "line" && l.type !== "dots") {  // a sliding mark needs no marker of its own
        l.marker.setAttribute("visibility", "hidden");
        continue;
      }
      l.marker.setAttribute("cx", this.sx(l.x[last]).toFixed(1));
      l.marker.setAttribute("cy", this.sy(l.y[last]).toFixed(1));
      l.marker.setAttribute("visibility", "visible");
    }
  }
}
const plots = D.plots.map(spec => new Plot(spec, $(D.keyPlots.includes(spec.id) ? "key-plots" : "other-plots")));
if (!D.plots.some(p => !D.keyPlots.includes(p.id))) { $("other-plots").remove(); $("other-title").remove(); }
if (!D.plots.length) $("key-plots").textContent = "This run file holds no series to plot.";

// ---- the page's text
if (D.changes.length) {
  $("changes").innerHTML = "<h2>Changes during the run</h2><ul>" + D.changes.map(c =>
    `<li>${timeName} = ${esc(timeText(c.t))}` +
    `${c.cycle === null || c.cycle === undefined ? "" : `, cycle ${esc(timeText(c.cycle))}`}: ${esc(c.text)}</li>`)
    .join("") + "</ul>";
}
$("notes").innerHTML = D.notes.map(n => `<li>${esc(n)}</li>`).join("");

// ---- the timeline
const slider = $("frame"), playButton = $("play");
slider.max = String(COUNT - 1);
let headerHeight = 0;
function setFrame(k) {
  frame = Math.max(0, Math.min(COUNT - 1, k));
  slider.value = String(frame);
  const thinned = F.index[COUNT - 1] + 1 !== COUNT || F.index[0] !== 0;
  $("frame-label").textContent = `frame ${frame + 1} of ${COUNT}` + (thinned ? ` (run frame ${F.index[frame]})` : "") +
    ` · ${timeName} = ${timeText(F.time[frame])} · step ${F.step[frame]}`;
  $("phase").textContent = F.phase[frame];
  showSettings();
  if (document.querySelector("header").offsetHeight !== headerHeight) fit();  // the settings took another line
  drawScene();
  for (const p of plots) p.update(false);
}
function stop() {
  clearInterval(timer);
  timer = null;
  playButton.textContent = "▶ Play";
}
function play() {
  if (timer) { stop(); return; }
  if (frame >= COUNT - 1) setFrame(0);
  const step = () => { if (frame >= COUNT - 1) stop(); else setFrame(frame + 1); };
  timer = setInterval(step, 1000 / Number($("fps").value));
  playButton.textContent = "❚❚ Pause";
}
slider.addEventListener("input", () => setFrame(Number(slider.value)));
playButton.addEventListener("click", play);
$("fps").addEventListener("change", () => { if (timer) { stop(); play(); } });
$("color-field").addEventListener("change", e => { colorField = e.target.value; drawLegend(); drawScene(); });
$("forces").addEventListener("change", e => { showForces = e.target.checked; drawLegend(); drawScene(); });
document.addEventListener("keydown", e => {
  if (["INPUT", "SELECT", "BUTTON"].includes(e.target.tagName)) return;
  if (e.key === " ") { e.preventDefault(); play(); }
  else if (e.key === "ArrowRight") setFrame(frame + 1);
  else if (e.key === "ArrowLeft") setFrame(frame - 1);
});
function fit() {
  headerHeight = document.querySelector("header").offsetHeight;
  const h = window.innerHeight - headerHeight - $("timeline").offsetHeight - 8;
  $("main").style.height = `${Math.max(440, h)}px`;
}
new ResizeObserver(drawScene).observe($("scene-box"));
window.addEventListener("resize", fit);
drawLegend();
showSettings();
fit();
setFrame(0);
window.handout = {setFrame, frame: () => frame, count: COUNT};
"""
