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

from ...errors import ParameterError
from ..settings import LabSettings
from .aggregation import AggregationPreset
from .base import Preset, View
from .block import BlockPreset
from .closed_path import ClosedPathPreset
from .compression import CompressionPreset
from .ratchet import EllipticPreset, Ratchet16Preset, RatchetPreset

PRESETS = {cls.name: cls for cls in (RatchetPreset, Ratchet16Preset, EllipticPreset, ClosedPathPreset, BlockPreset,
                                     AggregationPreset, CompressionPreset)}


def preset_settings(name: str, **changes) -> LabSettings:
    """The settings preset ``name`` starts from, with ``changes`` (validated)."""
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    return LabSettings().replace(**{**PRESETS[name].defaults, **changes})


def make_preset(name: str, settings: LabSettings | None = None) -> Preset:
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    return PRESETS[name](settings)


__all__ = ["PRESETS", "Preset", "View", "make_preset", "preset_settings"]
