"""GranLab's live browser lab (panel/bokeh dashboard and viser scene); see docs/lab.md."""
