"""One analysis of one state, as ``granlab analyze`` prints it and the lab's Analysis tab shows it.

:func:`analyze` returns an :class:`AnalysisReport`: ``values`` (JSON scalars and short lists,
what ``--json`` prints, NaN and None included), ``plots`` (arrays for the lab's plots and scene),
the wall time of each stage, and, for people:

- ``reasons``: why a value is missing (NaN, inf, None, or a number that stands for nothing, such
  as z* without a backbone), recorded by the analysis that knows it;
- :meth:`AnalysisReport.rows`: one :class:`Row` ``(key, label, text, note)`` per value. ``label``
  comes from :data:`LABELS`: words, the paper's symbol and equation, and a unit in brackets —
  ``[length]``, ``[force]``, ``[force/length]`` (a 2D stress), ``[length²]``, ``[1/length]`` in the
  state's own units (for Gilabert's preparations the paper's a and F0, or Pa without cohesion),
  ``[degrees]`` or ``[dimensionless]``; counts have none. ``text`` is the value (4 significant
  digits, "yes"/"no", lists in words) or "—" when it is missing, and then ``note`` says why;
  ``note`` also carries the message of a failed fit or a skipped enumeration;
- ``figures``: the pictures the report can draw, among :data:`FIGURES`.

The analyses:

- ``stiffness``: k = cKScᵀ with the dynamics' statuses, its null modes and their classification
  for a load increment (quasi-rigidity Sec. III E);
- ``status``: the critical contacts, the consistent state by minimum sliding, compared with the
  dynamics' statuses, and for M_c <= 16 all 2^M_c states (quasi-rigidity Sec. II);
- ``rigidity``: Gilabert's counts N_f + H = M + K and whether k is positive definite apart from
  rigid motions and rattlers;
- ``packing``: Φ, z, z*, x_k, force distributions, Rumpf, F_perc (Gilabert Secs. III-IV);
- ``fractal``: I(k), d_F, ξ and holes (Gilabert Sec. V).

The load increment of ``stiffness`` and ``status`` (``load``): ``walls`` raises every load on a
force-controlled wall in proportion; ``cell`` raises the target stress of each axis of a periodic
cell under stress control in proportion (its lengths are then bodies of k, Gilabert App. A);
``random`` pushes each disk with a random force (seeded); ``auto`` takes ``walls`` when walls are
loaded and ``random`` otherwise. The random forces act on the disks with at least two
interactions and add up to zero, so they excite neither rattlers, nor a disk hanging by one
contact (a mechanism of its own), nor a translation of the whole. The principle of minimum sliding holds for any increment.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import GranLabError, ParameterError
from . import ANALYSES, LOADS
from . import status
from . import stiffness as st
from .packing import packing_stats
from .states import require_forces

FIGURES = ("network", "forces", "structure", "mechanism")
"""What a report can draw: ``network`` the contacts coloured by the status minimum sliding gives
(status); ``forces`` the (N, T) of every interaction with T = ±sqrt(3) N (packing, with forces,
Gilabert Fig. 14); ``structure`` I(k) and its fit (fractal, unless the grid is all solid: I(k) is then zero);
``mechanism`` arrows along the mode that collapses the packing, or else the first null mode of k
(stiffness, when that mode moves disks)."""

MISSING = "—"
"""The text of a value that is missing; its row's note says why."""

LABELS = {
    # stiffness and status (quasi-rigidity paper)
    "disks": "Disks N",
    "dof": "Velocity components: 3 per disk, 1 per loaded wall or stress-controlled cell length (quasi-rigidity Eq. 15)",
    "contacts": "Interactions M: contacts and distant cohesive pairs",
    "sliding_contacts": "Contacts sliding in the dynamics",
    "distant_interactions": "Distant cohesive interactions",
    "nonzeros": "Non-zero entries of k = cKScᵀ",
    "asymmetry": "Asymmetry of k, max|k − kᵀ| / max|k| [dimensionless]",
    "load": "Load increment df_ext (quasi-rigidity Eq. 39)",
    "null_modes": "Null modes of k (quasi-rigidity Sec. III E)",
    "rigid_body_modes": "Null modes that are rigid-body motions",
    "rattler_modes": "Null modes of rattlers (3 per disk without interaction)",
    "unexcited_mechanisms": "Mechanisms the load does not excite",
    "collapse": "Collapse: the load excites a mechanism (Eq. 39 has no solution)",
    "unstable_directions": "Unstable directions, Q = vᵀkv < 0 (quasi-rigidity Eqs. 41–45)",
    "critical_contacts": "Critical contacts M_c (on the Coulomb cone)",
    "iterations": "Status flips by the principle of minimum sliding",
    "agrees_with_dynamics": "The dynamics' statuses are the consistent state",
    "dynamics_sliding": "Critical contacts sliding in the dynamics",
    "solver_sliding": "Critical contacts sliding by minimum sliding",
    "states_checked": "States enumerated, 2^M_c",
    "consistent_states": "Consistent states of the critical contacts (named by their disks)",
    "unstable_states": "Unstable states: Q(v, 𝕊) < 0 for some v (quasi-rigidity Eq. 41)",
    "bijective": "Consistency map C is a bijection (quasi-rigidity Eq. 5)",
    "enumeration_skipped": "Enumeration of the 2^M_c states",
    # rigidity (Gilabert App. A)
    "degrees_of_freedom": "Degrees of freedom N_f: 3 per disk, 1 per loaded wall or stress-controlled cell length (Gilabert App. A)",
    "constraints": "Constraints M: relative motions that carry forces",
    "floppy_modes": "Floppy modes K = dim null G",
    "hyperstaticity": "Degree of hyperstaticity H = dim null Gᵀ",
    "rank": "Rank of the rigidity matrix G",
    "balanced": "N_f + H = M + K holds (Gilabert Eq. 19)",
    "stiffness_null_modes": "Null modes of k",
    "stiffness_unstable_directions": "Unstable directions of k, Q < 0",
    "stiffness_positive_definite": "k positive definite apart from rigid motions and rattlers",
    "forces_known": "Contact forces known",
    # packing (Gilabert Secs. III-IV)
    "phi": "Solid fraction Φ [dimensionless]",
    "z": "Coordination number z: force-carrying disk–disk interactions per disk",
    "z_star": "Backbone coordination z* = z / (1 − x_0) (Gilabert Eq. 13)",
    "rattlers": "Rattlers: disks with no interaction above 10⁻⁴ F1",
    "packing.contacts": "Force-carrying disk–disk interactions",
    "particles": "Disks N",
    "coordination": "Local coordinations x_k: fraction of disks with k interactions",
    "force_unit": "Force unit of the histogram: F0, or ⟨N⟩ without cohesion [force]",
    "normal_force_histogram": "Histogram of N / force unit (Gilabert Fig. 9)",
    "theta_histogram": "Histogram of the angle θ between n and F (Gilabert Fig. 15) [degrees]",
    "mean_normal_force": "Mean normal force F_N = ⟨N⟩ [force]",
    "pressure": "Pressure P of the disk–disk stress [force/length]",
    "rumpf_force": "F_N by Rumpf, π ⟨d²⟩/⟨d⟩ P / (zΦ) (Gilabert Eq. 17) [force]",
    "rumpf_force_eq18": "F_N by Rumpf, 7πa P / (9 zΦ) (Gilabert Eq. 18) [force]",
    "percolation_force": "Force-percolation threshold F_perc (Gilabert Sec. IV B) [force]",
    # fractal (Gilabert Sec. V)
    "d_F": "Fractal dimension d_F (fit of Gilabert Eq. 28) [dimensionless]",
    "d_F_error": "One-sigma error of d_F",
    "xi": "Blob size ξ, the cut-off length of Eqs. 27–28 [length]",
    "xi_error": "One-sigma error of ξ [length]",
    "constant": "Constant Cst of Eq. 28 [length²]",
    "ell": "Length ℓ of Eq. 27 [length]",
    "fractal.phi": "Solid fraction Φ of the grid, the mean of χ [dimensionless]",
    "spacing": "Grid cell dx × dy (Sec. V C: about a/100) [length]",
    "shape": "Grid cells nx × ny",
    "fit_range": "k range of the fit [1/length]",
    "holes": "Holes: connected empty regions",
    "mean_hole_radius_w": "Weighted mean hole radius ⟨R⟩_w (Gilabert Eq. 30) [length]",
    "fit_error": "Fit of Eq. 28 to I(k) (Gilabert Eq. 25)",
}
"""The label of each value: ``key``, or ``kind.key`` where the same key means another thing in
that analysis (``contacts`` of ``packing`` counts only force-carrying disk-disk interactions)."""

MODE_VECTORS = 400
"""Null modes of k the stiffness analysis computes and classifies; more are only counted."""
RIGIDITY_MODE_VECTORS = 40
"""The same for the rigidity analysis, which needs them only to tell rigid motions apart."""
LOAD_TEXTS = {"walls": "the walls' loads raised in proportion",
              "random": "random forces on the disks, adding up to zero (seeded)"}
MAX_STATES_SHOWN = 4


def label(kind: str, key: str) -> str:
    """The label of the value ``key`` of the analysis ``kind`` (see :data:`LABELS`); the key
    itself if it has none."""
    return LABELS.get(f"{kind}.{key}") or LABELS.get(key, key)


@dataclass(frozen=True)
class Row:
    """One value of a report for people: its ``key`` in ``values``, its ``label``, its ``text``
    (``MISSING`` when there is none) and a ``note`` (why it is missing, or the message of a failed
    fit or a skipped enumeration; empty otherwise)."""

    key: str
    label: str
    text: str
    note: str = ""


@dataclass
class AnalysisReport:
    """``kind``, ``values`` (JSON-able), ``plots`` (arrays), ``timings`` (seconds per stage),
    ``reasons`` (key -> why that value is missing) and ``figures`` (among :data:`FIGURES`)."""

    kind: str
    values: dict
    plots: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    figures: tuple[str, ...] = ()

    def as_dict(self) -> ReportDict:
        return ReportDict(self, {"analysis": self.kind, **self.values, "timings_s": self.timings})

    def rows(self) -> list[Row]:
        """One :class:`Row` per value, in the order of ``values``."""
        return [self._row(key, value) for key, value in self.values.items()]

    def _row(self, key: str, value) -> Row:
        name = label(self.kind, key)
        if key in self.reasons:
            return Row(key, name, MISSING, self.reasons[key])
        if key == "fit_error":
            return Row(key, name, "failed" if value else "converged", value)
        if key == "enumeration_skipped":
            return Row(key, name, "skipped", value)
        if key in ("consistent_states", "unstable_states"):
            return Row(key, name, _states_text(value, self.plots["critical_names"]))
        if key == "load":
            return Row(key, name, LOAD_TEXTS.get(value, value))
        if key == "coordination":
            return Row(key, name, ", ".join(f"x_{k} = {x:.4g}" for k, x in enumerate(value)))
        if key.endswith("_histogram"):
            edges, fractions = value
            return Row(key, name, f"{len(fractions)} bins from {edges[0]:.4g} to {edges[-1]:.4g}")
        if key == "fit_range":
            return Row(key, name, " to ".join(_number_text(v) for v in value))
        if isinstance(value, (tuple, list)):
            return Row(key, name, " × ".join(_number_text(v) for v in value))
        return Row(key, name, _number_text(value))


class ReportDict(dict):
    """:meth:`AnalysisReport.as_dict`: the report as one JSON object, which also keeps the report
    itself (``report``) for whoever prints it for people."""

    def __init__(self, report: AnalysisReport, values: dict):
        super().__init__(values)
        self.report = report


def _number_text(value) -> str:
    """A scalar for people: "yes"/"no", a whole number, a float to 4 digits; ``MISSING`` for None,
    NaN or inf (whose reason the report's ``reasons`` hold)."""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return MISSING
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _states_text(states: list[str], names: tuple[str, ...]) -> str:
    """States of the critical contacts (bit strings, 1 = sliding, in the order of ``names``) in words:
    "none", or "2 states: contacts 3–7, 5–wall 'top' sliding; none sliding"."""
    if not states:
        return "none"
    described = [_state_text(bits, names) for bits in states[:MAX_STATES_SHOWN]]
    more = f"; … {len(states) - MAX_STATES_SHOWN} more" if len(states) > MAX_STATES_SHOWN else ""
    return f"{len(states)} state{'s' if len(states) > 1 else ''}: " + "; ".join(described) + more


def _state_text(bits: str, names: tuple[str, ...]) -> str:
    if not bits:
        return "no critical contact"
    sliding = [name for name, bit in zip(names, bits) if bit == "1"]
    if not sliding:
        return "none sliding"
    return f"contact{'s' if len(sliding) > 1 else ''} {', '.join(sliding)} sliding"


def _contact_names(state, net: st.Network, rows: np.ndarray) -> tuple[str, ...]:
    """The contacts ``rows`` of ``net`` named by their disks, "3–7", or disk and wall, "5–wall 'top'"."""
    return tuple(f"{net.first[a]}–{net.second[a]}" if net.second[a] >= 0
                 else f"{net.first[a]}–wall '{state.wall_names[net.wall[a]]}'" for a in rows)


def _unclassified(max_vectors: int) -> str:
    return (f"more than {max_vectors} null modes besides the rattlers': their vectors are not computed, "
            f"so they are not classified")


class _Clock:
    def __init__(self):
        self.timings = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timings[name] = now - self._last
        self._last = now


def _load_on(net: st.Network, dof: np.ndarray) -> np.ndarray:
    """The external load on the velocity components ``dof`` (-1: none), zero elsewhere."""
    out = np.zeros(net.dof)
    out[dof[dof >= 0]] = net.external[dof[dof >= 0]]
    return out


def load_increment(net: st.Network, load: str = "auto", seed: int = 0) -> tuple[np.ndarray, str]:
    """The load increment df_ext (one value per velocity component) and the name of its kind."""
    if load not in LOADS:
        raise ParameterError("load", load, f"one of {', '.join(LOADS)}")
    walls = _load_on(net, net.wall_dof)
    if load == "walls" or (load == "auto" and np.any(walls != 0.0)):
        if not np.any(walls != 0.0):
            raise GranLabError("load 'walls' needs a force-controlled wall with a load; this state has none "
                               "(use load 'cell' for a cell under stress control, or 'random')")
        return walls / np.linalg.norm(walls), "walls"
    if load == "cell":
        cell = _load_on(net, net.cell_dof)
        if not np.any(cell != 0.0):
            raise GranLabError("load 'cell' needs a periodic cell under stress control with a target stress; this "
                               "state has none (use load 'walls' or 'random')")
        return cell / np.linalg.norm(cell), "cell"
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


def _drawn_mode(mech: st.Mechanisms) -> np.ndarray | None:
    """The mode the lab draws as arrows: the one that collapses the packing, or else the first null mode."""
    if mech.collapse_mode is not None:
        return mech.collapse_mode
    if mech.modes is not None and mech.modes.shape[1]:
        return mech.modes[:, 0]
    return None


def _stiffness(state, clock, load, seed) -> AnalysisReport:
    require_forces(state, "the stiffness analysis")
    net = _network(state)
    k = st.stiffness_matrix(net)
    clock.lap("stiffness_matrix")
    increment, kind = load_increment(net, load, seed)
    mech = st.mechanisms(net, increment, max_vectors=MODE_VECTORS)
    clock.lap("mechanisms")
    asymmetry = abs(k - k.T).max() / max(abs(k).max(), 1e-300)
    values = {"disks": net.disks, "dof": net.dof, "contacts": net.contacts,
              "sliding_contacts": int(np.count_nonzero(net.sliding)),
              "distant_interactions": int(np.count_nonzero(net.distant)), "nonzeros": int(k.nnz),
              "asymmetry": float(asymmetry), "load": kind, **mech.as_dict()}
    plots = {"modes": mech.modes if mech.modes is not None else np.zeros((net.dof, 0)),
             "collapse_mode": mech.collapse_mode, "disks": net.disks}
    reasons = {} if mech.modes is not None else dict.fromkeys(("rigid_body_modes", "unexcited_mechanisms", "collapse"),
                                                              _unclassified(MODE_VECTORS))
    mode = _drawn_mode(mech)
    moves_disks = mode is not None and bool(np.any(mode[:3 * net.disks].reshape(-1, 3)[:, :2] != 0.0))
    return AnalysisReport("stiffness", values, plots, reasons=reasons, figures=("mechanism",) if moves_disks else ())


def _status(state, clock, load, seed) -> AnalysisReport:
    require_forces(state, "the contact-status analysis")
    net = _network(state)
    increment, kind = load_increment(net, load, seed)
    critical = status.critical_contacts(net)
    clock.lap("critical_contacts")
    solution = status.solve_status(net, increment, critical)
    clock.lap("minimum_sliding")
    values = {"contacts": net.contacts, "load": kind, "critical_contacts": int(len(critical)),
              "iterations": solution.iterations, "agrees_with_dynamics": solution.agrees_with_dynamics,
              "dynamics_sliding": int(np.count_nonzero(net.sliding[critical])),
              "solver_sliding": int(np.count_nonzero(solution.sliding[critical])),
              "states_checked": None, "consistent_states": None, "unstable_states": None, "bijective": None}
    limit = status.MAX_ENUMERATED if net.dof <= st.DENSE_SIZE else status.MAX_ENUMERATED_SPARSE
    reasons = {}
    if len(critical) <= limit:
        enumeration = status.enumerate_states(net, increment, critical)
        clock.lap("enumeration")
        values.update(enumeration.as_dict())
    else:
        values["enumeration_skipped"] = (f"{len(critical)} critical contacts: all states are enumerated for at "
                                         f"most {status.MAX_ENUMERATED} ({status.MAX_ENUMERATED_SPARSE} above "
                                         f"{st.DENSE_SIZE} velocity components)")
        reasons = dict.fromkeys(("states_checked", "consistent_states", "unstable_states", "bijective"),
                                "not enumerated: too many critical contacts")
    plots = {"first": net.first, "second": net.second, "normal_vectors": net.normal, "critical": critical,
             "critical_names": _contact_names(state, net, critical), "dynamics_sliding": net.sliding,
             "solver_sliding": solution.sliding, "normal": net.elastic_normal, "tangential": net.tangential}
    return AnalysisReport("status", values, plots, reasons=reasons, figures=("network",))


def _rigidity(state, clock, load, seed) -> AnalysisReport:
    net = _network(state)
    counts = st.rigidity(net)
    clock.lap("rigidity")
    mech = st.mechanisms(net, np.zeros(net.dof), max_vectors=RIGIDITY_MODE_VECTORS)
    clock.lap("stiffness_inertia")
    internal = None if mech.rigid_body is None else mech.count - mech.rattlers - mech.rigid_body
    values = {**counts.as_dict(), "stiffness_null_modes": mech.count, "stiffness_unstable_directions": mech.unstable,
              "stiffness_positive_definite": None if internal is None else bool(internal == 0 and mech.unstable == 0),
              "forces_known": state.forces_known}
    reasons = {} if internal is not None else {"stiffness_positive_definite": _unclassified(RIGIDITY_MODE_VECTORS)}
    return AnalysisReport("rigidity", values, reasons=reasons)


def _packing(state, clock, load, seed) -> AnalysisReport:
    stats = packing_stats(state)
    clock.lap("packing")
    return AnalysisReport("packing", stats.as_dict(), {"normal": stats.normal, "tangential": stats.tangential},
                          reasons=stats.reasons, figures=("forces",) if stats.forces_known else ())


def _fractal(state, clock, load, seed) -> AnalysisReport:
    from .fractal import fractal_analysis

    result = fractal_analysis(state.positions, state.radii, state.box_lengths, lap=clock.lap)
    return AnalysisReport("fractal", result.as_dict(),
                          {"k": result.k, "intensity": result.intensity, "fitted": result.fitted},
                          reasons=result.reasons, figures=("structure",) if 0.0 < result.phi < 1.0 else ())


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
