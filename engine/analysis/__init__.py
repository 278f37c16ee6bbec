"""Analysis: pure functions of snapshots and recorded series, returning result dataclasses."""

ANALYSES = ("stiffness", "status", "rigidity", "packing", "fractal")
"""What ``granlab analyze`` and the lab's Analysis tab run (:mod:`granlab.engine.analysis.report`); named
here so that the command line lists them without importing the analyses."""
LOADS = ("auto", "walls", "cell", "random")
"""Load increments of the stiffness and status analyses (:func:`granlab.engine.analysis.report.load_increment`)."""
