"""The lab's keys: Space play/pause, → step, Alt+R restart, Alt+Shift+R reset settings, ? the list.

One small component per tab, drawn as the "Keys" button of the header, holds the page's key
handler and the dialog that lists the keys. A key the page acts on becomes an ``action`` the
dashboard carries out as if its button had been pressed. Keys typed into a text box, or pressed
on a focused button or slider, keep their usual meaning (Space presses the focused button, the
arrows move the focused slider). A focused slider of :data:`SLIDER_STEPS` moves by its normal
step with the arrows, its fine step with Shift and its coarse step with PageUp/PageDown;
Home/End take it to its ends (noUiSlider's own keys). The one-key shortcuts (Space, →, ?) can be
turned off in the Preferences (:mod:`.preferences`); the button, reached by Tab, opens the list too.
"""

from __future__ import annotations

import param
from panel.reactive import ReactiveHTML

KEYS = (("Space", "play / pause"), ("→", "one step (a frame's worth of simulated time)"),
        ("Alt+R", "restart: the same settings from t = 0"), ("Alt+Shift+R", "reset the settings to the preset's own"),
        ("?", "this list"), ("Tab / Shift+Tab", "the next / previous control"),
        ("Space or Enter", "press the focused button, tick the focused box"),
        ("← → on a slider", "move it (Shift: finer; PageUp/PageDown: coarser; Home/End: to its ends)"),
        ("↑ ↓ on a menu", "choose the previous / next entry"), ("Esc", "close this list"),
        ("Preferences", "one-key shortcuts off: Space, → and ? do nothing; the buttons and Alt keys still act"))
"""Every key of the page and what it does, as the dialog lists them."""

SLIDER_STEPS = {"phase-slider": (1.0, 5.0, 45.0), "friction-slider": (0.01, 0.05, 0.2),
                "damping-slider": (0.01, 0.05, 0.2)}
"""Per slider (its css class): the fine (Shift+arrow), normal (arrow) and coarse (PageUp/Down) steps."""

HANDLER = """
const help = dialog
if (window.__granlabKeys) window.removeEventListener("keydown", window.__granlabKeys, true)
let count = 0
const send = (action) => { count += 1; data.action = action + ":" + count }
window.__granlabKeys = (event) => {
  const path = event.composedPath()
  const target = path[0]
  const tag = target.tagName || ""
  const typing = (tag === "INPUT" && !["checkbox", "radio", "button", "range"].includes(target.type))
                 || tag === "TEXTAREA" || tag === "SELECT" || target.isContentEditable
  if (typing || help.open) return
  const single = data.single_keys && !event.altKey && !event.ctrlKey && !event.metaKey
  if (event.key === "?" && single) { event.preventDefault(); help.showModal(); return }
  const handle = target.classList && target.classList.contains("noUi-handle")
  if (handle) {
    const host = path.find((el) => el.classList && [...el.classList].some((name) => name in data.steps))
    const keys = {ArrowRight: 1, ArrowUp: 1, PageUp: 1, ArrowLeft: -1, ArrowDown: -1, PageDown: -1}
    if (host == null || !(event.key in keys)) return
    const view = Bokeh.index.query_one((v) => v.el === host)
    const model = view == null ? null : view.model
    if (model == null || model.disabled) return
    const name = [...host.classList].find((name) => name in data.steps)
    const [fine, normal, coarse] = data.steps[name]
    const step = event.key.startsWith("Page") ? coarse : (event.shiftKey ? fine : normal)
    const moved = Math.min(model.end, Math.max(model.start, model.value + keys[event.key] * step))
    const value = Number((Math.round(moved / fine) * fine).toFixed(10))
    event.preventDefault()
    event.stopPropagation()
    model.setv({value: value, value_throttled: value})
    return
  }
  if (!data.enabled) return
  const button = tag === "BUTTON" || tag === "INPUT" || tag === "A"
  const play = path.some((el) => el.classList && el.classList.contains("play-button"))
  // Space on Play/Pause too: a button clicks on Space's release, which may find it drawn anew
  if (event.code === "Space" && single && (!button || play)) { event.preventDefault(); send("play-pause") }
  else if (event.key === "ArrowRight" && single && !button) { event.preventDefault(); send("step") }
  else if (event.altKey && event.code === "KeyR") {
    event.preventDefault()
    send(event.shiftKey ? "defaults" : "restart")
  }
}
window.addEventListener("keydown", window.__granlabKeys, true)
// bokeh draws a button anew when its label or colour changes ("Pause" -> "Play", the named speed in
// effect): the focused element goes and the keyboard would be back at the top of the page. The
// control of the widget last focused by the keyboard gets it back.
let lastHost = null
if (window.__granlabFocus) {
  window.removeEventListener("focusin", window.__granlabFocus, true)
  window.removeEventListener("mousedown", window.__granlabMouse, true)
  clearInterval(window.__granlabRefocus)
}
window.__granlabFocus = (event) => {
  const path = event.composedPath()
  lastHost = path.find((el) => el.shadowRoot && el.shadowRoot.contains(path[0])) || null
}
window.__granlabMouse = () => { lastHost = null }
window.addEventListener("focusin", window.__granlabFocus, true)
window.addEventListener("mousedown", window.__granlabMouse, true)
window.__granlabRefocus = setInterval(() => {
  if (lastHost == null || document.activeElement !== document.body || !lastHost.isConnected) return
  const control = lastHost.shadowRoot.querySelector("button:not([disabled]), select:not([disabled]), "
                                                    + "input:not([disabled]), .noUi-handle")
  if (control != null) control.focus()
}, 100)
"""


def _rows() -> str:
    return "".join(f"<tr><th>{key}</th><td>{what}</td></tr>" for key, what in KEYS)


class Keyboard(ReactiveHTML):
    """The page's key handler and its "Keys" button; ``action`` is the last key's action with a
    count ("step:3"), so that the same key twice is two changes. ``enabled`` False (a viewer's
    page): only the list of keys opens."""

    action = param.String(default="")
    enabled = param.Boolean(default=True)
    single_keys = param.Boolean(default=True, doc="Space, → and ? act (the Preferences' one-key shortcuts)")
    steps = param.Dict(default=SLIDER_STEPS)

    _template = f"""
<button id="open" class="keys-button" onclick="${{script('show')}}" aria-haspopup="dialog"
        aria-label="Keys ?: keyboard help" title="The keys of this page (?)">Keys ?</button>
<dialog id="dialog" class="keys-dialog" aria-label="Keys">
  <h2>Keys</h2>
  <table>{_rows()}</table>
  <button id="close" class="keys-close" onclick="${{script('hide')}}">Close</button>
</dialog>
<style>
  .keys-button {{ font: 13px sans-serif; height: 31px; padding: 0 10px; border: 1px solid #ccc; border-radius: 4px;
                 background: #f6f7f9; cursor: pointer; }}
  .keys-dialog {{ font: 16px sans-serif; border: 2px solid #444; border-radius: 8px; padding: 16px 24px; }}
  .keys-dialog th {{ text-align: left; padding: 4px 16px 4px 0; white-space: nowrap; }}
  .keys-dialog h2 {{ margin: 0 0 8px 0; }}
  .keys-close {{ font: 15px sans-serif; margin-top: 12px; padding: 4px 14px; }}
  button:focus-visible {{ outline: 3px solid #e65100; outline-offset: 2px; }}  /* the dashboard's FOCUS_CSS */
</style>
"""
    _scripts = {"render": HANDLER, "show": "dialog.showModal()", "hide": "dialog.close()"}
