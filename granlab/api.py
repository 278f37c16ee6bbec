"""The functions of GranLab's Python API (:mod:`granlab` names them; see its docstring)."""

from __future__ import annotations

from pathlib import Path

from granlab.engine import (ContactLaw, DivergenceError, GranLabError, Integration, ParameterError, ParticleState,
                            PeriodicCell, Simulation, Wall, box_walls)
from granlab.engine.analysis import ANALYSES
from granlab.engine.analysis.report import AnalysisReport, analyze
from granlab.engine.analysis.states import PackingState, read_state, read_states
from granlab.engine.io.h5md import RunWriter
from granlab.engine.io.scene import load_scene
from granlab.engine.params import TANGENTIAL_MODELS
from granlab.engine.protocols import prepare
from granlab.engine.protocols.presets import PRESETS, Preset, make_preset, preset_settings
from granlab.engine.studies import RatchetCurve, RatchetStudy, cycle_sample, model_sim

#: what :mod:`granlab` offers from here (checked against its own list by the tests)
__all__ = ["ANALYSES", "AnalysisReport", "ContactLaw", "DivergenceError", "GranLabError", "Integration", "PRESETS",
           "PackingState", "ParameterError", "ParticleState", "PeriodicCell", "Preset", "RatchetCurve", "Simulation",
           "TANGENTIAL_MODELS", "Wall", "analyze", "box_walls", "compress", "export", "load_scene", "preset", "ratchet",
           "read", "read_all", "render", "save", "snapshot", "table"]


def preset(name: str, **settings) -> Preset:
    """The lab preset ``name`` (one of ``PRESETS``) with ``settings`` (those of the lab's controls:
    ``particles``, ``seed``, ``friction``, ``tangential_model``...), ready to ``advance(steps)``."""
    return make_preset(name, preset_settings(name, **settings))


def compress(particles: int = 16, seed: int = 0, pressure: float = 1.0, friction: float = 0.2) -> Simulation:
    """A biaxial box of ``particles`` disks compressed to ``pressure`` and then given ``friction``
    (ratcheting Sec. IV B 1, paper units), in equilibrium by Gilabert's criteria."""
    return prepare.compress(particles, seed=seed, pressure=pressure, friction=friction).sim


def ratchet(box: Simulation, model: str = "cundall-strack", cycles: int = 40, amplitude: float = 0.2,
            period: float = 10.0, phase: float | None = None, reference_cycle: int | None = None,
            dt_factor: float = 0.2) -> RatchetCurve:
    """Cycle a copy of ``box`` (from :func:`compress`; left as it is) with the tangential spring
    ``model`` under ``q(t) = amplitude (1 - cos 2πt/period)`` (``phase`` in radians for the elliptic
    loading): the box lengths at the start of each cycle, γ from ``reference_cycle`` (default 30 %
    of the cycles) and the paper's verdict with the strain per cycle ``verdict.dgamma``."""
    study = RatchetStudy(particles=box.particles.count, samples=1, cycles=cycles, models=(model,),
                         amplitude=amplitude, period=period, phase=phase, reference_cycle=reference_cycle,
                         dt_factor=dt_factor)
    return cycle_sample(model_sim(box, study, model), study)


def snapshot(sim: Simulation, source: str = "simulation") -> PackingState:
    """The state of ``sim`` now, as every analysis reads it."""
    return PackingState.from_snapshot(sim.snapshot(), source=source)


def read(path, frame: int = -1, **options) -> PackingState:
    """Frame ``frame`` of a GranLab run file, an H5MD file, a LAMMPS dump or an extended XYZ file;
    ``options``: ``contacts`` (a LAMMPS dump local of the contacts), ``contact_columns``, ``law``
    (e.g. ``{"friction": 0.5, "normal_stiffness": 1e3}`` for another code's file)."""
    return read_state(path, frame, **options)


def read_all(path, **options) -> list[PackingState]:
    """Every frame of a file (as :func:`read`)."""
    return read_states(path, **options)


def save(sim: Simulation, path, overwrite: bool = False) -> Path:
    """Write the state of ``sim`` as a run file with one frame and a checkpoint (``granlab run
    --resume`` continues it; every command and :func:`read` read it)."""
    with RunWriter(path, sim, protocol={"command": "granlab.save"}, overwrite=overwrite) as writer:
        writer.write_frame(sim)
        writer.write_checkpoint(sim)
    return Path(path)


def export(run_file, format: str, out, frames=None, force: bool = False) -> dict:
    """Frames of a run file for another tool (``format`` in ``EXPORT_FORMATS``), as ``granlab export``."""
    from granlab.engine.io.export import export_run

    return export_run(run_file, format, out, frames, force)


def render(run_file, out, frames=None, size: str = "1280x720", color: str = "rotation", forces: bool = True,
           fps: float = 10.0, force: bool = False) -> dict:
    """Pictures or a movie of a run file (``.png``, ``.gif``, ``.mp4``), as ``granlab render``."""
    from granlab.app.media.render import render_run

    return render_run(run_file, out, frames, size, color, forces, fps, force)


def table(report: AnalysisReport):
    """The values of an analysis report in words (label with symbol, equation and unit; value;
    why a value is missing), as a pandas DataFrame."""
    import pandas

    rows = report.rows()
    return pandas.DataFrame({"value": [row.text for row in rows], "note": [row.note for row in rows]},
                            index=pandas.Index([row.label for row in rows], name=report.kind))
