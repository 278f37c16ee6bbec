"""The page a tab gets while the lab's engine is starting: how far the first run's compile is, and
the lab itself (the page reloads into the dashboard) once the engine runs."""

from __future__ import annotations

import html

import panel as pn

REFRESH_MS = 500


def progress_text(starting: dict) -> str:
    """What the page says of ``starting`` (:attr:`granlab.app.lab.server.Lab.starting`)."""
    if starting["state"] == "failed":
        return f"The engine did not start: {starting['error']}"
    if not starting["total"]:
        return "Starting the engine..."
    doing = f" ({starting['current']})" if starting["current"] else ""
    return (f"Compiling the simulation's kernels, first run only (later starts take seconds): "
            f"{min(starting['done'] + 1, starting['total'])} of {starting['total']}{doing}, "
            f"{starting['seconds']:.0f} s")


def starting_page(lab) -> pn.Column:
    """A page that follows ``lab.starting`` every half second and reloads once ``lab.engine`` runs."""
    message = pn.pane.HTML(html.escape(progress_text(lab.starting)), css_classes=["starting-text"],
                           styles={"font-size": "26px", "line-height": "1.4"}, sizing_mode="stretch_width")
    bar = pn.indicators.Progress(value=0, max=1, height=24, sizing_mode="stretch_width",
                                 css_classes=["starting-progress"], bar_color="primary")
    after = pn.pane.HTML("The lab opens here by itself as soon as they are ready. <code>granlab compile</code> "
                         "compiles every kernel ahead of time, the night before a class.",
                         styles={"font-size": "20px", "color": "#444"}, sizing_mode="stretch_width")
    reload = pn.widgets.TextInput(value="", visible=False)
    reload.jscallback(value="window.location.reload()")

    def refresh():
        if lab.engine is not None:
            reload.value = "ready"
            return
        starting = lab.starting
        message.object = html.escape(progress_text(starting))
        bar.max, bar.value = max(1, starting["total"]), min(starting["done"], max(1, starting["total"]))

    pn.state.add_periodic_callback(refresh, period=REFRESH_MS)
    return pn.Column(pn.pane.HTML("<h1 style='font-size:40px;margin:0'>GranLab</h1>"), message, bar, after, reload,
                     styles={"margin": "4vh auto", "padding": "0 3vw", "max-width": "1100px"},
                     sizing_mode="stretch_width")
