"""GranLab's live browser lab (panel/bokeh dashboard and viser scene); see the README."""
