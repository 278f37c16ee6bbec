"""One Preferences dialog per tab, as in the best teaching simulations: how this screen shows the lab.

A "Preferences" button of the header opens a dialog (the browser's own ``<dialog>``: modal, Esc
closes it, focus goes back to the button) with three choices for this screen only:

- **projector mode**: large text and thick lines in every plot (also ``?profile=projector`` in a link);
- **reduced motion**: the plots, readout and legend redrawn every :data:`CALM_SECONDS`, and a
  viewer's 2D scene too, rather than several times a second; on at first where the system asks
  for reduced motion (``prefers-reduced-motion``). The presenter's 3D scene is the experiment
  itself and keeps moving as the disks do (Pause stops it);
- **one-key shortcuts** (Space, →, ?): on by default; off, only the keys with Alt and a focused
  control's own keys act (WCAG 2.1.4: a screen reader or speech input types single characters).

What the disks are coloured by and which contacts are watched are the scene's, the same on every
screen: they stay in the View controls.
"""

from __future__ import annotations

import param
from panel.reactive import ReactiveHTML

CALM_SECONDS = 2.0
"""How often a screen in reduced motion redraws its plots and its viewer's scene."""

CHOICES = (("projector", "Projector mode", "large text and thick lines in every plot"),
           ("reduced_motion", "Reduced motion",
            f"plots and readout redrawn every {CALM_SECONDS:g} s (a viewer's scene too); the 3D scene is the "
            "experiment itself and moves with it: Pause stops it"),
           ("single_keys", "One-key shortcuts", "Space play/pause, → one step, ? the keys; off: only Alt+R, "
                                                "Alt+Shift+R and a focused control's own keys"))
"""Each choice: its parameter, its label and what it does, as the dialog says it."""


def _choice(name: str, label: str, what: str) -> str:
    return (f'<label class="prefs-choice"><input type="checkbox" id="{name}_box" class="prefs-{name}" '
            f'onchange="${{script(\'{name}_changed\')}}"></input>'
            f'<span><b>{label}</b><span class="prefs-what">{what}</span></span></label>')


def _changed(name: str) -> str:
    return f"data.{name} = {name}_box.checked"


def _show(name: str) -> str:
    return f"{name}_box.checked = data.{name}"


SYSTEM_MOTION = """
window.__granlabReducedMotion = data.reduced_motion
if (!data.motion_chosen && window.matchMedia("(prefers-reduced-motion: reduce)").matches) {
  data.motion_chosen = true
  data.reduced_motion = true
}
"""
"""On the first drawing: the system's reduced-motion setting, unless this screen already chose."""

REDUCED_MOTION = "reduced_motion_box.checked = data.reduced_motion; window.__granlabReducedMotion = data.reduced_motion"
"""The viewer's scene (a same-origin frame) reads ``__granlabReducedMotion`` from its parent page."""


class Preferences(ReactiveHTML):
    """This screen's preferences: ``projector``, ``reduced_motion`` and ``single_keys``."""

    projector = param.Boolean(default=False)
    reduced_motion = param.Boolean(default=False)
    single_keys = param.Boolean(default=True)
    motion_chosen = param.Boolean(default=False, doc="reduced motion chosen here or by a link: the system's stays unread")

    _template = f"""
<button id="open" class="prefs-button" onclick="${{script('show')}}" aria-haspopup="dialog">Preferences</button>
<dialog id="dialog" class="prefs-dialog" aria-label="Preferences">
  <h2>Preferences</h2>
  <p class="prefs-scope">For this screen only; the scene's colours and watched contacts are in View.</p>
  {"".join(_choice(*choice) for choice in CHOICES)}
  <button id="close" class="prefs-close" onclick="${{script('hide')}}">Close</button>
</dialog>
<style>
  .prefs-button {{ font: 13px sans-serif; height: 31px; padding: 0 10px; border: 1px solid #ccc; border-radius: 4px;
                  background: #f6f7f9; cursor: pointer; }}
  .prefs-dialog {{ font: 16px sans-serif; border: 2px solid #444; border-radius: 8px; padding: 16px 24px;
                  max-width: 34em; }}
  .prefs-dialog h2 {{ margin: 0 0 4px 0; }}
  .prefs-scope {{ margin: 0 0 12px 0; color: #444; font-size: 14px; }}
  .prefs-choice {{ display: flex; gap: 10px; align-items: flex-start; margin: 10px 0; cursor: pointer; }}
  .prefs-choice input {{ width: 20px; height: 20px; margin-top: 2px; flex: none; }}
  .prefs-what {{ display: block; font-size: 14px; color: #444; }}
  .prefs-close {{ font: 15px sans-serif; margin-top: 12px; padding: 4px 14px; }}
  button:focus-visible, input:focus-visible {{ outline: 3px solid #e65100; outline-offset: 2px; }}
</style>
"""
    _scripts = {"render": "; ".join(_show(name) for name, _, _ in CHOICES) + SYSTEM_MOTION,
                "show": "dialog.showModal()", "hide": "dialog.close()",
                "projector_changed": _changed("projector"), "projector": _show("projector"),
                "reduced_motion_changed": "data.motion_chosen = true; " + _changed("reduced_motion"),
                "reduced_motion": REDUCED_MOTION,
                "single_keys_changed": _changed("single_keys"), "single_keys": _show("single_keys")}
