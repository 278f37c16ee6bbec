"""What the lab is doing, in words, for whoever cannot see the screen well: a screen reader's live
region, updated every few seconds, and one alert when the run starts again.

:func:`describe` says it from the lab's status and the scene's state (pure Python, tested without
a browser); :class:`LiveText` holds the two regions in the page. Their elements stay and only
their text changes, which is what makes a screen reader read a change out.
"""

from __future__ import annotations

import param
from panel.reactive import ReactiveHTML

from ..media.drawing import COLOR_FIELDS
from .plots import compact

UPDATE_SECONDS = 5.0
"""How often the polite region says the state again (a screen reader reads each change out)."""
COLOUR_WORDS = dict(zip(COLOR_FIELDS, ("its rotation angle", "its number of contacts", "its pressure",
                                       "whether a contact of it slides")))


def describe(status: dict, scene: dict) -> str:
    """The state in a few sentences: preset, stage, time, cycle, Δγ per cycle with the verdict,
    Φ, z, sliding contacts, then what the scene shows."""
    readout = status.get("readout") or {}
    parts = [f"{status.get('title', status.get('preset', ''))}: {status.get('stage', '')}, "
             f"{status.get('state', '')}, time {compact(status.get('time', 0.0))}"]
    if "cycle" in status:
        parts[-1] += f", cycle {status['cycle']}"
    fit = status.get("strain") or {}
    if fit:
        verdict = "ratcheting" if fit.get("ratcheting") else "not ratcheting"
        parts.append(f"strain change per cycle {compact(fit.get('dgamma'))}, {verdict}")
    if "phi" in readout:
        parts.append(f"packing fraction {readout['phi']:.3f}")
    if "z" in readout:
        parts.append(f"{readout['z']:.2f} contacts per disk")
    if "sliding" in readout:
        parts.append(f"{readout['sliding']} contact{'s' if readout['sliding'] != 1 else ''} sliding")
    if readout.get("restitution") is not None:
        parts.append(f"{readout['collisions']} collisions, the last with restitution {readout['restitution']:.3f} "
                     f"against {readout['predicted']:.3f} predicted")
    text = "; ".join(parts) + "."
    return f"{text} {scene_text(scene)}" if scene.get("disks") else text


def scene_text(scene: dict) -> str:
    """What the scene draws: the disks and their colour, the contacts, the boundary, the watched contacts."""
    boundary = (f"between {scene['walls']} walls" if scene.get("walls") else
                "in a periodic cell" if scene.get("cell") is not None else "")
    parts = [f"The scene shows {scene['disks']} disks {boundary}".rstrip()
             + f", each coloured by {COLOUR_WORDS.get(scene.get('color_field'), scene.get('color_field'))}",
             f"{scene.get('contacts', 0)} contacts drawn as lines as thick as their force"]
    if scene.get("watched"):
        parts.append(f"{scene['watched']} watched contacts in their own colours")
    return "; ".join(parts) + "."


class LiveText(ReactiveHTML):
    """Two regions no one sees and a screen reader reads: ``polite`` (read when the reader is
    free) and ``alert`` (read at once: a restart)."""

    polite = param.String(default="")
    alert = param.String(default="")

    # the text itself in the region's element (a string is otherwise a child model of its own)
    _child_config = {"polite": "literal", "alert": "literal"}

    _template = """
<div id="polite" class="live" role="status" aria-live="polite" aria-atomic="true">${polite}</div>
<div id="alert" class="live" role="alert" aria-atomic="true">${alert}</div>
<style>
  .live { position: absolute; width: 1px; height: 1px; overflow: hidden; clip: rect(0 0 0 0); white-space: nowrap; }
</style>
"""
