"""The status of the critical contacts by the principle of minimum sliding (quasi-rigidity Sec. II):
the contacts on the Coulomb cone, the consistency map C of their statuses (Eq. 5) from the response
of k to a load increment, the consistent state found by flipping statuses (minimum sliding), and
for a few critical contacts every one of their 2^M_c states with its stability (Eqs. 41-45).
Built on the stiffness matrix of :mod:`granlab.engine.analysis.stiffness`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from . import stiffness
from .report import AnalysisReport, Clock
from .states import require_forces
from .stiffness import (NORMAL, ROLLING, TANGENTIAL, ZERO_TOLERANCE, Network, compatibility, count_below,
                        rattler_disks, relative_velocities, response, stiffness_matrix)

LABELS = {
    "contacts": stiffness.LABELS["contacts"],
    "load": stiffness.LABELS["load"],
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
}
"""The label of each value of the status analysis (:func:`run`)."""
MAX_STATES_SHOWN = 4
"""States a report names in words; the rest are counted."""


def critical_contacts(net: Network, tolerance: float = 1e-6) -> np.ndarray:
    """Touching contacts on the Coulomb cone: | |F_t| - mu N^e | <= tolerance mu N^e (quasi-rigidity
    Sec. II C), with mu finite and N^e > 0."""
    if not np.isfinite(net.friction) or net.friction <= 0.0:
        return np.zeros(0, dtype=np.int64)
    limit = net.friction * net.elastic_normal
    on_cone = (np.abs(np.abs(net.tangential) - limit) <= tolerance * limit) & (limit > 0.0) & ~net.distant
    return np.flatnonzero(on_cone)


def _v_tilde(net: Network, rel: np.ndarray, rows) -> np.ndarray:
    """Ṽ = mu (K_n/K_t) V_n + V_t sgn D_t (quasi-rigidity Eq. 10) for the contacts ``rows`` from their
    relative velocities ``rel`` (normal, tangential): dF̃/dt = -K_t Ṽ for a non-sliding contact
    (Eq. 11), so Ṽ > 0 would carry it out of the cone. Critical contacts only: mu is finite there."""
    kt = np.where(net.kt[rows] > 0.0, net.kt[rows], np.inf)
    return net.friction * net.kn[rows] / kt * rel[:, 0] + rel[:, 1] * net.sign_dt[rows]


def _sliding_set(net: Network, critical: np.ndarray, bits) -> np.ndarray:
    """The dynamics' statuses with those of the ``critical`` contacts set to ``bits``."""
    sliding = net.sliding.copy()
    sliding[critical] = np.asarray(bits, dtype=bool)
    return sliding


def consistency(net: Network, load_increment: np.ndarray, critical: np.ndarray,
                bits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the state ``bits`` (1 = sliding) of the critical contacts: the quasi-static velocities,
    Ṽ of the critical contacts and the consistency of each with the principle of minimum sliding
    (sliding needs Ṽ > 0, non-sliding Ṽ <= 0)."""
    bits = np.asarray(bits, dtype=bool)
    v = response(net, load_increment, _sliding_set(net, critical, bits))
    vt = _v_tilde(net, relative_velocities(net, v)[critical], critical)
    return v, vt, np.where(bits, vt > 0.0, vt <= 0.0)


@dataclass(frozen=True)
class StatusSolution:
    """The globally consistent state found by :func:`solve_status`: ``sliding`` (M booleans),
    ``critical`` contact indices, ``iterations``, the velocities ``v``, and whether the dynamics'
    own statuses agree on the critical contacts (``agrees_with_dynamics``)."""

    sliding: np.ndarray
    critical: np.ndarray
    iterations: int
    velocities: np.ndarray
    agrees_with_dynamics: bool


def solve_status(net: Network, load_increment: np.ndarray, critical: np.ndarray | None = None,
                 max_iterations: int | None = None) -> StatusSolution:
    """The principle of minimum sliding applied iteratively (quasi-rigidity Sec. II C): start from
    the dynamics' statuses, compute the velocities, flip the critical contact whose consistency is
    most violated, and repeat until every critical contact is consistent."""
    critical = critical_contacts(net) if critical is None else np.asarray(critical, dtype=np.int64)
    start = net.sliding[critical]
    bits = start.copy()
    limit = max_iterations if max_iterations is not None else 20 * max(1, len(critical))
    for iteration in range(limit + 1):
        v, vt, ok = consistency(net, load_increment, critical, bits)
        if ok.all():
            return StatusSolution(_sliding_set(net, critical, bits), critical, iteration, v,
                                  bool(np.array_equal(bits, start)))
        worst = int(np.argmax(np.where(ok, -np.inf, np.abs(vt))))
        bits[worst] = not bits[worst]
    raise ParameterError("contact status", f"no consistent state after {limit} flips",
                         "a packing whose states are all stable (quasi-rigidity Eq. 41); check with enumerate_states")


@dataclass(frozen=True)
class StatusEnumeration:
    """Every state of the critical contacts (quasi-rigidity Sec. II D): ``states_checked`` = 2^M_c,
    ``consistent_states`` (bit strings, contact order of ``critical``, 1 = sliding), ``unstable_states``
    (Q(v, 𝕊) < 0 for some v: the theorem's premise fails there), and ``bijective``: whether the
    consistency map C of Eq. 5 is a bijection."""

    critical: np.ndarray
    states_checked: int
    consistent_states: list[str]
    unstable_states: list[str]
    bijective: bool

    def as_dict(self) -> dict:
        return {"critical_contacts": len(self.critical), "states_checked": self.states_checked,
                "consistent_states": self.consistent_states, "unstable_states": self.unstable_states,
                "bijective": self.bijective}


MAX_ENUMERATED = 16
MAX_ENUMERATED_SPARSE = 6
"""Above DENSE_SIZE velocity components each state costs a sparse factorisation and an inertia
count (0.7 s at 16 800): at most 2^6 states are enumerated there."""


def enumerate_states(net: Network, load_increment: np.ndarray, critical: np.ndarray | None = None,
                     tolerance: float = ZERO_TOLERANCE) -> StatusEnumeration:
    """All 2^M_c states of the M_c <= 16 critical contacts: the consistency map C (Eq. 5), whether it
    is a bijection, the consistent states, and the states that are unstable (the symmetric part of
    k(𝕊) has a negative eigenvalue, outside the disks without interactions).

    k(𝕊) is assembled as k(all critical stuck) plus, for each sliding critical contact, its own
    change c_a (K S_slide - K S_stick)_a c_aᵀ (quasi-rigidity Eq. 24 changes one block), so a state
    costs one dense solve and one symmetric eigenvalue problem. Above DENSE_SIZE velocity components
    (at most MAX_ENUMERATED_SPARSE critical contacts) each state is solved and checked sparse."""
    critical = critical_contacts(net) if critical is None else np.asarray(critical, dtype=np.int64)
    mc = len(critical)
    if mc > MAX_ENUMERATED:
        raise ParameterError("critical contacts", mc, f"at most {MAX_ENUMERATED} to enumerate 2^M_c states")
    load = np.asarray(load_increment, dtype=float)
    if net.dof > stiffness.DENSE_SIZE:  # read at the call: tests force the sparse path
        if mc > MAX_ENUMERATED_SPARSE:
            raise ParameterError("critical contacts", mc, f"at most {MAX_ENUMERATED_SPARSE} to enumerate 2^M_c states "
                                                          f"of a packing above {stiffness.DENSE_SIZE} velocity components")
        return _enumerate_sparse(net, load, critical, tolerance)
    stuck = _sliding_set(net, critical, np.zeros(mc, dtype=bool))
    base = stiffness_matrix(net, stuck).toarray()
    changes = []
    for a in critical:
        one = stuck.copy()
        one[a] = True
        changes.append(stiffness_matrix(net, one).toarray() - base)
    c = compatibility(net, (NORMAL, TANGENTIAL, ROLLING)).toarray()
    loose = rattler_disks(net)
    keep = np.ones(net.dof, dtype=bool)
    for offset in range(3):
        keep[3 * loose + offset] = False
    delta = 1e-10 * float(np.abs(np.diag(base)).max() or 1.0)
    free = np.ones(net.dof, dtype=bool) if net.fixed is None else ~net.fixed
    keep &= free
    scale = float(np.abs(np.diag(base)[keep]).max()) if keep.any() else 0.0
    images, consistent, unstable = set(), [], []
    for code in range(2 ** mc):
        bits = np.array([(code >> b) & 1 for b in range(mc)], dtype=bool)
        k = base + sum((changes[b] for b in np.flatnonzero(bits)), np.zeros_like(base))
        v = np.zeros(net.dof)
        v[free] = np.linalg.solve((k + delta * np.eye(net.dof))[np.ix_(free, free)], load[free])
        vt = _v_tilde(net, (c.T @ v).reshape(-1, 3)[critical], critical)
        ok = np.where(bits, vt > 0.0, vt <= 0.0)
        images.add(tuple(ok))
        label = "".join("1" if b else "0" for b in bits)
        if ok.all():
            consistent.append(label)
        sym = 0.5 * (k + k.T)[np.ix_(keep, keep)]
        if scale > 0 and np.linalg.eigvalsh(sym)[0] < -tolerance * scale:
            unstable.append(label)
    return StatusEnumeration(critical, 2 ** mc, consistent, unstable, len(images) == 2 ** mc)


def _enumerate_sparse(net: Network, load: np.ndarray, critical: np.ndarray, tolerance: float) -> StatusEnumeration:
    """:func:`enumerate_states` for large packings: per state, k(𝕊) assembled, one sparse solve for
    the consistency and one inertia count (:func:`count_below`) for the stability."""
    mc = len(critical)
    loose = rattler_disks(net)
    keep = np.ones(net.dof, dtype=bool)
    for offset in range(3):
        keep[3 * loose + offset] = False
    if net.fixed is not None:
        keep &= ~net.fixed
    index = np.flatnonzero(keep)
    images, consistent, unstable = set(), [], []
    for code in range(2 ** mc):
        bits = np.array([(code >> b) & 1 for b in range(mc)], dtype=bool)
        _, _, ok = consistency(net, load, critical, bits)
        images.add(tuple(ok))
        label = "".join("1" if b else "0" for b in bits)
        if ok.all():
            consistent.append(label)
        k = stiffness_matrix(net, _sliding_set(net, critical, bits))
        sym = ((k + k.T) * 0.5).tocsr()[index][:, index].tocsc()
        scale = float(np.abs(sym.diagonal()).max()) if len(index) else 0.0
        if scale > 0 and count_below(sym, -tolerance * scale) > 0:
            unstable.append(label)
    return StatusEnumeration(critical, 2 ** mc, consistent, unstable, len(images) == 2 ** mc)


# ---------------------------------------------------------------------------------------- the analysis

@dataclass(frozen=True)
class StatusResult:
    """What the status analysis found: the stiffness ``network`` (its ``sliding`` are the
    dynamics' statuses), the consistent state by minimum sliding (``solution``), the critical
    contacts named by their disks (``critical_names``, in the order of ``solution.critical``) and,
    for few enough critical contacts, every state (``enumeration``, else None)."""

    network: Network
    solution: StatusSolution
    critical_names: tuple[str, ...]
    enumeration: StatusEnumeration | None


def states_text(states: list[str], names: tuple[str, ...]) -> str:
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


def _contact_names(state, net: Network, rows: np.ndarray) -> tuple[str, ...]:
    """The contacts ``rows`` of ``net`` named by their disks, "3–7", or disk and wall, "5–wall 'top'"."""
    return tuple(f"{net.first[a]}–{net.second[a]}" if net.second[a] >= 0
                 else f"{net.first[a]}–wall '{state.wall_names[net.wall[a]]}'" for a in rows)


def run(state, clock: Clock, load: str, seed: int) -> AnalysisReport:
    """The critical contacts, the consistent state by minimum sliding, compared with the dynamics'
    statuses, and for M_c <= 16 all 2^M_c states (quasi-rigidity Sec. II); the result is a
    :class:`StatusResult`."""
    require_forces(state, "the contact-status analysis")
    net = stiffness.network_with_contacts(state)
    increment, kind = stiffness.load_increment(net, load, seed)
    critical = critical_contacts(net)
    clock.lap("critical_contacts")
    solution = solve_status(net, increment, critical)
    clock.lap("minimum_sliding")
    values = {"contacts": net.contacts, "load": kind, "critical_contacts": int(len(critical)),
              "iterations": solution.iterations, "agrees_with_dynamics": solution.agrees_with_dynamics,
              "dynamics_sliding": int(np.count_nonzero(net.sliding[critical])),
              "solver_sliding": int(np.count_nonzero(solution.sliding[critical])),
              "states_checked": None, "consistent_states": None, "unstable_states": None, "bijective": None}
    names = _contact_names(state, net, critical)
    texts = {"load": stiffness.LOAD_TEXTS.get(kind, kind)}
    limit = MAX_ENUMERATED if net.dof <= stiffness.DENSE_SIZE else MAX_ENUMERATED_SPARSE
    reasons, enumeration = {}, None
    if len(critical) <= limit:
        enumeration = enumerate_states(net, increment, critical)
        clock.lap("enumeration")
        values.update(enumeration.as_dict())
        texts.update((key, states_text(values[key], names)) for key in ("consistent_states", "unstable_states"))
    else:
        values["enumeration_skipped"] = (f"{len(critical)} critical contacts: all states are enumerated for at "
                                         f"most {MAX_ENUMERATED} ({MAX_ENUMERATED_SPARSE} above "
                                         f"{stiffness.DENSE_SIZE} velocity components)")
        reasons = dict.fromkeys(("states_checked", "consistent_states", "unstable_states", "bijective"),
                                "not enumerated: too many critical contacts")
    return AnalysisReport("status", values, StatusResult(net, solution, names, enumeration), reasons=reasons,
                          texts=texts, figures=("network",))
