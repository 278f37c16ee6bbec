"""GranLab's Python API, for notebooks and scripts: ``import granlab as gl``.

Build and run
    ``Simulation``, ``ParticleState``, ``ContactLaw``, ``Integration``, ``PeriodicCell``, ``Wall``,
    ``box_walls`` (the engine's own classes); ``load_scene(path_or_name)``; ``preset(name, **settings)``
    (a lab preset, run headless with ``.advance(steps)``); ``compress(particles, seed)`` (the biaxial
    box of ratcheting Sec. IV B 1) and ``ratchet(box, model, cycles)`` (cycled with one tangential
    spring: γ per cycle and the paper's verdict); ``TANGENTIAL_MODELS``.
States and files
    ``snapshot(sim)``; ``read(path, frame=-1, ...)`` and ``read_all(path)`` (GranLab run files, H5MD,
    LAMMPS dumps with ``contacts=``, extended XYZ; ``law=`` for another code's file); ``save(sim, path)``;
    ``export(run_file, format, out)`` (ParaView, OVITO, LAMMPS, MDAnalysis); ``render(run_file, out)``.
Analyses
    ``analyze(state, kind)`` for ``kind`` in ``ANALYSES``; ``table(report)`` its values in words.
Figures and the lab
    ``show(figure)`` (bokeh, inline, offline); ``strain_figure(curves)``, ``analysis_figure(state,
    report)``, ``force_network_figure(state)``; ``lab(preset)`` the live lab in a notebook cell.
"""

import importlib

__version__ = "0.1.0"

#: where each public name lives. Nothing is imported until it is used: ``import granlab`` is
#: free, ``granlab.engine`` costs the engine alone, and only the lab and its figures bring panel,
#: bokeh and matplotlib.
_HOMES = {
    "granlab.api": ("ANALYSES", "AnalysisReport", "ContactLaw", "DivergenceError", "GranLabError", "Integration",
                    "PRESETS", "PackingState", "ParameterError", "ParticleState", "PeriodicCell", "Preset",
                    "RatchetCurve", "Simulation", "TANGENTIAL_MODELS", "Wall", "analyze", "box_walls", "compress",
                    "export", "load_scene", "preset", "ratchet", "read", "read_all", "render", "save", "snapshot",
                    "table"),
    "granlab.engine.io.export": ("EXPORT_FORMATS",),
    "granlab.app.notebook": ("NotebookLab", "analysis_figure", "force_network_figure", "lab", "show",
                             "strain_figure"),
}
_HOME = {name: module for module, names in _HOMES.items() for name in names}

__all__ = sorted(_HOME)


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module 'granlab' has no attribute {name!r}")
    value = getattr(importlib.import_module(_HOME[name]), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
