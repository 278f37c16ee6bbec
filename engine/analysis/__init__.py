"""Analysis: pure functions of snapshots and recorded series, returning result dataclasses.

The analyses ``granlab analyze``, the lab's Analysis tab and :func:`granlab.analyze` run are the
entries of :data:`ANALYSES`. An analysis is one module defining ``LABELS`` (a label for each value
it reports, see :mod:`granlab.engine.analysis.report`) and ``run(state, clock, load, seed)``
returning an :class:`~granlab.engine.analysis.report.AnalysisReport` whose ``result`` is its own
dataclass; adding one is its module, its line here (or :func:`register`) and its docs.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType


@dataclass(frozen=True)
class Analysis:
    """An analysis: its ``name`` (the command line's and the lab's), the ``module`` that runs it
    (imported only when it runs, so that listing the analyses imports none of them) and its
    ``title`` in words."""

    name: str
    module: str
    title: str

    def load(self) -> ModuleType:
        return importlib.import_module(self.module)


ANALYSES = {analysis.name: analysis for analysis in (
    Analysis("stiffness", "granlab.engine.analysis.stiffness",
             "the stiffness matrix k = cKScᵀ, its null modes and what a load increment excites (quasi-rigidity "
             "Sec. III E)"),
    Analysis("status", "granlab.engine.analysis.status",
             "the critical contacts' consistent status by minimum sliding, and every state of a few "
             "(quasi-rigidity Sec. II)"),
    Analysis("rigidity", "granlab.engine.analysis.rigidity",
             "the counts N_f + H = M + K of the rigidity matrix, and whether k is positive definite (Gilabert "
             "App. A)"),
    Analysis("packing", "granlab.engine.analysis.packing",
             "Φ, z, z*, x_k, the force distributions, Rumpf's estimate and F_perc (Gilabert Secs. III–IV)"),
    Analysis("fractal", "granlab.engine.analysis.fractal",
             "the structure factor I(k), d_F, ξ and the holes (Gilabert Sec. V)"))}
"""The one registry of analyses, by name; the command line, the lab and the Python API list these."""

LOADS = ("auto", "walls", "cell", "random")
"""Load increments of the stiffness and status analyses (:func:`granlab.engine.analysis.stiffness.load_increment`)."""


def register(analysis: Analysis) -> None:
    """Add ``analysis`` to :data:`ANALYSES` (a plug-in's own analysis); its module must be importable."""
    ANALYSES[analysis.name] = analysis
