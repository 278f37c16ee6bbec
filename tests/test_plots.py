"""The lab's plots as bokeh models, without a browser: what a viewer would see before and after
the first points."""

import numpy as np
import pytest

from granlab.app.lab import plots
from granlab.engine.protocols.teaching import restitution


def test_the_strain_plot_shows_its_legend_only_with_its_points():
    """Before the first cycle's point the legend's labels would stand without their marks."""
    plot = plots.StrainPlot(reference=2)
    legend = plot.figure.legend[0]
    plot.refresh({})
    assert not legend.visible and "not reached yet" in plot.figure.title.text
    plot.feed("cycles", {"cycle": [0, 1, 2, 3], "gamma": [0.0, 1e-8, 2e-8, 3e-8]}, False, {})
    plot.refresh({})
    assert legend.visible and plot.points.data["cycle"].tolist() == [2.0, 3.0]


def test_the_load_strain_colour_bar_ticks_whole_cycles():
    """Each cycle's shade spans the cycle ± 0.5: ticks between cycles ("cycle -0.4") would mean nothing."""
    bar = next(item for item in plots.LoadStrainPlot().figure.right if type(item).__name__ == "ColorBar")
    assert bar.ticker.min_interval == 1


def test_the_restitution_plot_draws_the_buffers_rows_and_titles_the_last_collision():
    """A page pulls the engine's buffers as arrays: a new tab on a run with its collisions, or none yet."""
    plot = plots.make_plot("restitution", "t", {})
    empty = {"collision": np.array([]), "zeta": np.array([]), "restitution": np.array([]), "predicted": np.array([])}
    plot.feed("collisions", empty, True, {})
    assert plot.empty() and plot.figure.title.text == plot.title
    rows = {"collision": np.array([1.0, 2.0]), "zeta": np.array([0.3, 0.5]),
            "restitution": np.array([0.3723, 0.1630]), "predicted": np.array([restitution(0.3), restitution(0.5)])}
    plot.feed("collisions", rows, True, {})
    assert list(plot.points.data["zeta"]) == [0.3, 0.5]
    assert plot.figure.title.text == "e_N = 0.1630 measured, 0.1630 predicted (ζ = 0.50)"
    line = plot.figure.renderers[0].data_source.data
    assert np.interp(0.5, line["x"], line["y"]) == pytest.approx(restitution(0.5), rel=1e-4)  # the formula's line


def test_each_collision_is_a_loop_of_its_own_in_the_force_overlap_plot():
    """Samples of two collisions: segments join samples of one collision only, also across pulls."""
    plot = plots.make_plot("collision-force", "t", {})
    rows = {"t": np.array([0.1, 0.2, 0.3, 1.1]), "collision": np.array([1.0, 1.0, 1.0, 2.0]),
            "overlap": np.array([0.001, 0.002, 0.001, 0.001]), "force": np.array([90.0, 80.0, -20.0, 90.0]),
            "spring": np.array([10.0, 20.0, 10.0, 10.0])}
    plot.feed("collision", rows, True, {})
    force = plot.lines["force"][0].data
    assert list(force["y0"]) == [90.0, 80.0] and list(force["y1"]) == [80.0, -20.0]
    plot.feed("collision", {key: np.array([value]) for key, value in
                            (("t", 1.2), ("collision", 2.0), ("overlap", 0.002), ("force", 80.0), ("spring", 20.0))},
              False, {})
    assert list(plot.lines["force"][0].data["y0"]) == [90.0, 80.0, 90.0]  # from collision 2's first sample


@pytest.mark.parametrize("share, kept", [(1.0, plots.LINE_ROLLOVER), (plots.VIEWER_SHARE, 10000)])
def test_a_viewers_page_keeps_a_quarter_of_the_rows_and_says_what_it_holds(share, kept):
    """The server holds a copy of every page's plots: a viewer's keeps the last 10 000 rows of a time
    series (the presenter's 40 000), the newest ones, and its bytes are what those rows take."""
    plot = plots.make_plot("coordination", "t", {"time": ("t", "z")})
    plot.share = share
    for start in range(0, 50000, 5000):
        t = np.arange(start, start + 5000, dtype=float)
        plot.feed("time", {"t": t, "z": 4.0 + 0 * t}, start == 0, {})
    assert len(plot.source.data["t"]) == kept and plot.source.data["t"][-1] == 49999.0
    assert plot.nbytes() == 2 * 8 * kept


def test_the_strain_plot_keeps_its_last_cycles_measured_from_the_reference():
    """A school day cycles some 20 000 times: the plot keeps the last CYCLES_ROLLOVER cycles (a viewer's
    page its share), their strain still counted from the reference cycle, and draws those."""
    plot = plots.StrainPlot(reference=2)
    plot.share = plots.VIEWER_SHARE
    kept = plot.rows(plots.CYCLES_ROLLOVER)
    status = {"fit_from": {"cycle": 2, "after": ""}}
    for start in range(0, 3 * kept, 100):
        cycles = np.arange(start, start + 100)
        plot.feed("cycles", {"cycle": cycles, "gamma": 1e-8 * cycles}, start == 0, status)
        plot.refresh(status)
    assert kept <= len(plot.cycles) <= kept + kept // 4 + 2 and 2 in plot.cycles
    drawn = plot.points.data["cycle"]
    assert drawn[-1] == 3 * kept - 1 and len(drawn) < kept + kept // 4 + 1
    assert plot.points.data["strain"][-1] == pytest.approx(1e-8 * (3 * kept - 1 - 2))
    assert plot.figure.x_range.start == drawn[0] - 0.5
