"""One analysis of one state, as ``granlab analyze`` prints it and the lab's Analysis tab plots it.

:func:`analyze` returns an :class:`AnalysisReport`: ``values`` (JSON scalars and short lists,
what ``--json`` prints) and ``plots`` (arrays for the lab's plots and scene), with the wall
time of each stage. The analyses:

- ``stiffness``: k = cKScᵀ with the dynamics' statuses, its null modes and their classification
  for a load increment (quasi-rigidity Sec. III E);
- ``status``: the critical contacts, the consistent state by minimum sliding, compared with the
  dynamics' statuses, and for M_c <= 16 all 2^M_c states (quasi-rigidity Sec. II);
- ``rigidity``: Gilabert's counts N_f + H = M + K and whether k is positive definite apart from
  rigid motions and rattlers;
- ``packing``: Φ, z, z*, x_k, force distributions, Rumpf, F_perc (Gilabert Secs. III-IV);
- ``fractal``: I(k), d_F, ξ and holes (Gilabert Sec. V).

The load increment of ``stiffness`` and ``status`` (``load``): ``walls`` raises every load on a
force-controlled wall in proportion; ``random`` pushes each disk with a random force (seeded);
``auto`` takes ``walls`` when walls are loaded and ``random`` otherwise (a periodic cell of
fixed size has no load of its own). The random forces act on the disks with at least two
interactions and add up to zero, so they excite neither rattlers, nor a disk hanging by one
contact (a mechanism of its own), nor a translation of the whole. The principle of minimum sliding holds for any increment.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import GranLabError, ParameterError
from . import ANALYSES, LOADS
from . import stiffness as st
from .packing import packing_stats
from .states import require_forces



@dataclass
class AnalysisReport:
    """``kind``, ``values`` (JSON-able), ``plots`` (arrays), ``timings`` (seconds per stage)."""

    kind: str
    values: dict
    plots: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"analysis": self.kind, **self.values, "timings_s": self.timings}

    def lines(self) -> list[tuple[str, str]]:
        """``(key, text)`` of every value, for people: numbers to 6 digits, a histogram as its
        range, a long list cut after 12 values (the CLI and the lab's Analysis tab show these)."""
        return [(key, describe(key, value)) for key, value in self.values.items()]


def describe(key: str, value) -> str:
    """One value of a report as text (see :meth:`AnalysisReport.lines`)."""
    if isinstance(value, float):
        return f"{value:.6g}"
    if key.endswith("_histogram") and value is not None:
        return f"{len(value[1])} bins from {value[0][0]:.4g} to {value[0][-1]:.4g}"
    if isinstance(value, list):
        return ", ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in value[:12]) + \
            (f", ... ({len(value)} values)" if len(value) > 12 else "")
    return str(value)


class _Clock:
    def __init__(self):
        self.timings = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timings[name] = now - self._last
        self._last = now


def load_increment(net: st.Network, load: str = "auto", seed: int = 0) -> tuple[np.ndarray, str]:
    """The load increment df_ext (one value per velocity component) and the name of its kind."""
    if load not in LOADS:
        raise ParameterError("load", load, f"one of {', '.join(LOADS)}")
    walls = net.external
    if load == "walls" or (load == "auto" and np.any(walls != 0.0)):
        if not np.any(walls != 0.0):
            raise GranLabError("load 'walls' needs a force-controlled wall with a load; this state has none "
                               "(use load 'random')")
        return walls / np.linalg.norm(walls), "walls"
    rng = np.random.default_rng(seed)
    out = np.zeros(net.dof)
    interactions = np.bincount(net.first, minlength=net.disks) + np.bincount(net.second[net.second >= 0],
                                                                             minlength=net.disks)
    bound = np.flatnonzero(interactions >= 2)
    forces = rng.normal(size=(len(bound), 2))
    forces -= forces.mean(axis=0)
    out[3 * bound], out[3 * bound + 1] = forces[:, 0], forces[:, 1]
    return out / np.linalg.norm(out), "random"


def _network(state) -> st.Network:
    net = st.network(state)
    if net.contacts == 0:
        raise GranLabError("the state has no contacts: there is no stiffness matrix, status or rigidity to analyse")
    return net


def _stiffness(state, clock, load, seed) -> AnalysisReport:
    require_forces(state, "the stiffness analysis")
    net = _network(state)
    k = st.stiffness_matrix(net)
    clock.lap("stiffness_matrix")
    increment, kind = load_increment(net, load, seed)
    mech = st.mechanisms(net, increment)
    clock.lap("mechanisms")
    asymmetry = abs(k - k.T).max() / max(abs(k).max(), 1e-300)
    values = {"disks": net.disks, "dof": net.dof, "contacts": net.contacts,
              "sliding_contacts": int(np.count_nonzero(net.sliding)),
              "distant_interactions": int(np.count_nonzero(net.distant)), "nonzeros": int(k.nnz),
              "asymmetry": float(asymmetry), "load": kind, **mech.as_dict()}
    plots = {"modes": mech.modes if mech.modes is not None else np.zeros((net.dof, 0)),
             "collapse_mode": mech.collapse_mode, "disks": net.disks}
    return AnalysisReport("stiffness", values, plots)


def _status(state, clock, load, seed) -> AnalysisReport:
    require_forces(state, "the contact-status analysis")
    net = _network(state)
    increment, kind = load_increment(net, load, seed)
    critical = st.critical_contacts(net)
    clock.lap("critical_contacts")
    solution = st.solve_status(net, increment, critical)
    clock.lap("minimum_sliding")
    values = {"contacts": net.contacts, "load": kind, "critical_contacts": int(len(critical)),
              "iterations": solution.iterations, "agrees_with_dynamics": solution.agrees_with_dynamics,
              "dynamics_sliding": int(np.count_nonzero(net.sliding[critical])),
              "solver_sliding": int(np.count_nonzero(solution.sliding[critical])),
              "states_checked": None, "consistent_states": None, "unstable_states": None, "bijective": None}
    limit = st.MAX_ENUMERATED if net.dof <= st.DENSE_SIZE else st.MAX_ENUMERATED_SPARSE
    if len(critical) <= limit:
        enumeration = st.enumerate_states(net, increment, critical)
        clock.lap("enumeration")
        values.update(enumeration.as_dict())
    else:
        values["enumeration_skipped"] = (f"{len(critical)} critical contacts: all states are enumerated for at "
                                         f"most {st.MAX_ENUMERATED} ({st.MAX_ENUMERATED_SPARSE} above "
                                         f"{st.DENSE_SIZE} velocity components)")
    plots = {"first": net.first, "second": net.second, "normal_vectors": net.normal, "critical": critical,
             "dynamics_sliding": net.sliding, "solver_sliding": solution.sliding,
             "normal": net.elastic_normal, "tangential": net.tangential}
    return AnalysisReport("status", values, plots)


def _rigidity(state, clock, load, seed) -> AnalysisReport:
    net = _network(state)
    counts = st.rigidity(net)
    clock.lap("rigidity")
    mech = st.mechanisms(net, np.zeros(net.dof), max_vectors=40)
    clock.lap("stiffness_inertia")
    internal = None if mech.rigid_body is None else mech.count - mech.rattlers - mech.rigid_body
    values = {**counts.as_dict(), "stiffness_null_modes": mech.count, "stiffness_unstable_directions": mech.unstable,
              "stiffness_positive_definite": None if internal is None else bool(internal == 0 and mech.unstable == 0),
              "forces_known": state.forces_known}
    return AnalysisReport("rigidity", values)


def _packing(state, clock, load, seed) -> AnalysisReport:
    stats = packing_stats(state)
    clock.lap("packing")
    return AnalysisReport("packing", stats.as_dict(), {"normal": stats.normal, "tangential": stats.tangential})


def _fractal(state, clock, load, seed) -> AnalysisReport:
    from .fractal import fractal_analysis

    result = fractal_analysis(state.positions, state.radii, state.box_lengths, lap=clock.lap)
    return AnalysisReport("fractal", result.as_dict(),
                          {"k": result.k, "intensity": result.intensity, "fitted": result.fitted})


_RUNNERS = {"stiffness": _stiffness, "status": _status, "rigidity": _rigidity, "packing": _packing,
            "fractal": _fractal}


def analyze(state, kind: str, load: str = "auto", seed: int = 0) -> AnalysisReport:
    """Run the analysis ``kind`` (one of :data:`ANALYSES`) on ``state``."""
    if kind not in _RUNNERS:
        raise ParameterError("analysis", kind, f"one of {', '.join(ANALYSES)}")
    clock = _Clock()
    report = _RUNNERS[kind](state, clock, load, seed)
    report.timings = dict(clock.timings, total=sum(clock.timings.values()))
    return report
