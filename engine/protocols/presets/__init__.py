"""The lab's presets: each sets up a figure of the papers and advances it step by step.

A preset owns its simulation(s) and the protocol around them (compression then cyclic
loading, a closed path carried over and over, a load ramp, aggregation then compression).
The lab's engine thread calls :meth:`Preset.advance`, then reads :meth:`Preset.rows`,
:meth:`Preset.views` and :meth:`Preset.watched`; controls reach it through :meth:`Preset.apply`.

Everything a preset records is sampled in simulated time, never by how often someone asks:
each preset has a clock unit (a load cycle, a loop of the closed path, Gilabert's T_0) that
lasts :meth:`Preset.cycle_time`, and :meth:`Preset.advance` stops on its way at every sample
time to record the time series (``samples_per_cycle`` per unit), the paths of watched
contacts (``path_samples_per_cycle``) and, through ``on_frame``, the frames a replay keeps
(the setting ``frames_per_cycle``). A fast preset therefore draws smooth paths however fast it runs.
Nothing here imports a UI library: presets run headless in tests.

Adding a preset is one module here (a subclass of :class:`~.base.Preset`), its teaching text in
``static/teaching/NAME.md`` and one entry of :data:`PRESETS`.
"""

from __future__ import annotations

import dataclasses
import math

from ...errors import ParameterError
from ..settings import CONTROL_LABELS, LabSettings
from .aggregation import AggregationPreset
from .base import Preset, View
from .block import BlockPreset
from .closed_path import ClosedPathPreset
from .collision import CollisionPreset
from .compression import CompressionPreset
from .ratchet import EllipticPreset, Ratchet16Preset, RatchetPreset

PRESETS = {cls.name: cls for cls in (RatchetPreset, Ratchet16Preset, EllipticPreset, ClosedPathPreset, BlockPreset,
                                     CollisionPreset, AggregationPreset, CompressionPreset)}


def preset_settings(name: str, **changes) -> LabSettings:
    """The settings preset ``name`` starts from, with ``changes`` (validated)."""
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    return LabSettings().replace(**{**PRESETS[name].defaults, **changes})


LINK_KEYS = ("preset", "speed")
"""What a link's query holds besides the settings that differ from the preset's own."""
FIELD_TYPES = {field.name: {"int": int, "str": str}.get(field.type, float) for field in dataclasses.fields(LabSettings)}


def setup_query(name: str, settings: LabSettings) -> dict[str, str]:
    """The query of a link to this setup: the preset, each setting that differs from its own
    and the speed (a named speed by its name). :func:`parse_setup` reads it back exactly."""
    own = preset_settings(name)
    query = {"preset": name}
    for field, value in dataclasses.asdict(settings).items():
        if field != "speed" and value != getattr(own, field):
            query[field] = query_text(value)
    query["speed"] = speed_text(name, settings.speed)
    return query


def speed_text(name: str, speed: float) -> str:
    """A link's speed: one of preset ``name``'s named speeds by its name, another by its value."""
    named = [key for key, value in PRESETS[name].speeds.items() if value == speed]
    return named[0] if named else query_text(speed)


def query_text(value) -> str:
    """A setting's value as a link says it."""
    if isinstance(value, float):
        # repr: the shortest text that reads back exactly (less a whole number's ".0")
        return "inf" if value == math.inf else repr(value).removesuffix(".0")
    return str(value)


def parse_setup(query: dict[str, str]) -> tuple[str, dict]:
    """The preset and the changes of its settings a link's query names (its other keys, the
    page's own, are not looked at); raises :class:`ParameterError` naming the first key or value
    that is not allowed. The values themselves are checked by :func:`preset_settings`."""
    name = query.get("preset", "ratchet")
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    changes = {}
    for key, text in query.items():
        if key not in FIELD_TYPES:
            continue
        kind = FIELD_TYPES[key]
        if key == "speed" and text in PRESETS[name].speeds:
            changes[key] = PRESETS[name].speeds[text]
        elif kind is str:
            changes[key] = text
        else:
            try:
                changes[key] = kind(text.replace("max", "inf")) if kind is float else int(text)
            except ValueError:
                allowed = "a whole number" if kind is int else "a number, or inf"
                if key == "speed":
                    allowed += " or a named speed: " + ", ".join(PRESETS[name].speeds)
                raise ParameterError(key, text, allowed) from None
    preset_settings(name, **changes)
    return name, changes


def setup_text(name: str, changes: dict) -> str:
    """A link's setup in words: the preset's title and the changes of its settings."""
    shown = ", ".join(f"{CONTROL_LABELS.get(key, key)} = {'∞' if value == math.inf else value}"
                      for key, value in changes.items())
    return f"the link's setup: {PRESETS[name].title}" + (f" with {shown}" if shown else "")


def make_preset(name: str, settings: LabSettings | None = None) -> Preset:
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    return PRESETS[name](settings)


__all__ = ["PRESETS", "Preset", "View", "make_preset", "parse_setup", "preset_settings", "setup_query", "setup_text"]
