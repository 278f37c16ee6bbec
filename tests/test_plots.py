"""The lab's plots as bokeh models, without a browser: what a viewer would see before and after
the first points."""

from granlab.app.lab import plots


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
