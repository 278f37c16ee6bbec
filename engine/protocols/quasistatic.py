"""A quasi-static stepper: a slowly changing load followed with the stiffness matrix and the
consistent contact status (quasi-rigidity Secs. II-III and its closing call for such a method).

From a packing in equilibrium, the load ``f(λ)`` goes from the present loads (``λ = 0``) to the
targets (``λ = 1``) in steps. Each step

1. builds k = cKScᵀ at the present configuration (:mod:`granlab.engine.analysis.stiffness`),
   finds the consistent status of the contacts on the Coulomb cone by the principle of minimum
   sliding (:func:`granlab.engine.analysis.status.solve_status`) and solves ``k Δu = Δf`` for the
   displacements (the predictor, quasi-rigidity Eq. 39 times the step);
2. moves the disks and walls, and corrects by Newton iterations on the exact contact forces of
   the new configuration (elastic normal force from the overlap, the tangential spring loaded by
   the step's relative displacement and returned to the Coulomb cone) until the largest
   out-of-balance force is below ``tolerance`` times the mean normal force. The candidate
   contacts are the pairs (and disk-wall pairs) closer than :data:`NEAR` radii: each touches, with
   its stiffness, where its overlap is positive, so contacts open and close within the iterations
   (each one named in ``events``).

A step that does not converge is halved, at most ``max_halvings`` times. The stepper stops with a
named reason (:data:`STOP_REASONS`): the target reached; k not positive (an unstable state,
quasi-rigidity Eq. 41); the load exciting a mechanism, so that no nearby equilibrium exists (a
collapse: the block of Fig. 2 pushed past ``mu F_n``); no consistent status; or a change of the
contact network after which no equilibrium is found.

Supported: disks and walls (fixed, or force-controlled and then bodies of k), any tangential
model, every normal law (each gives its tangent stiffness), gravity and constant forces on disks. Not supported (a
:class:`granlab.engine.errors.ParameterError` says so): periodic axes, cohesion and rolling
resistance (their thresholds have no consistent status here). Disks with infinite mass or
inertia, and kinematic disks, keep those degrees of freedom fixed.

:func:`follow_dynamically` ramps the same loads in the dynamics, for the comparison of
``granlab quasistatic --compare``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from ..analysis import stiffness
from ..analysis.status import MAX_ENUMERATED_SPARSE, critical_contacts, enumerate_states, solve_status
from ..errors import DivergenceError, GranLabError, ParameterError
from ..kernels import normal as normal_laws
from ..params import NORMAL, TANGENTIAL, Load, friction_coefficient
from ..simulation import Simulation
from ..state import KIND_FIXED, KIND_KINEMATIC, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK, WALL_FORCE

STOP_REASONS = {
    "target": "the target load is reached",
    "unstable": "k is not positive: an unstable state (quasi-rigidity Eq. 41)",
    "collapse": "the load excites a mechanism: no equilibrium near this load (a collapse)",
    "no_status": "no consistent contact status (minimum sliding does not converge)",
    "network": "the contact network changed and no equilibrium was found after the change",
}
"""Why :func:`follow` stops, by key."""
TOLERANCE = 1e-9
"""Largest out-of-balance force of an equilibrium, as a fraction of the mean normal force."""
MAX_ITERATIONS = 40
"""Newton iterations of one step before it counts as not converging."""
NEAR = 0.1
"""Pairs closer than this fraction of the smallest radius are candidate contacts: they touch, and
carry force, once their overlap is positive (twice the largest move of a step)."""
MAX_STEPS = 100_000
"""The most load steps :func:`follow` takes (hours at 400 disks)."""
MAX_UNIQUE = 10
"""Critical contacts up to which ``check_unique`` enumerates every state (above 1500 velocity
components, :data:`granlab.engine.analysis.status.MAX_ENUMERATED_SPARSE`)."""
MAX_MOVE = 0.05
"""Largest displacement of one step, as a fraction of the smallest radius, before it is halved."""


@dataclass(frozen=True)
class Targets:
    """The loads at ``λ = 1``: ``walls`` {name: load of a force-controlled wall (its ``base``: a force,
    or a pressure for a wall loaded per length)}; ``forces`` {disk index: (F_x, F_y)}."""

    walls: dict = field(default_factory=dict)
    forces: dict = field(default_factory=dict)


@dataclass(frozen=True)
class QuasiStaticPath:
    """What :func:`follow` did. Per step reached (the first row is the start): ``load`` λ,
    ``wall_offsets (S, W)``, ``positions (S, N, 2)``, ``sliding`` contacts, ``critical`` contacts at
    the step's start, ``flips`` of minimum sliding, ``iterations`` of Newton, ``consistent_states``
    (from enumerating every state of the critical contacts, if ``check_unique``; else -1).
    ``stop`` is a key of :data:`STOP_REASONS` and ``stop_detail`` says where and why; ``events``
    lists the contacts opened and closed; ``solves`` counts the linear solves; ``rattlers`` marks
    the disks that carry no force at the end (fewer than two contacts, no load of their own)."""

    load: np.ndarray
    wall_offsets: np.ndarray
    positions: np.ndarray
    angles: np.ndarray
    sliding: np.ndarray
    critical: np.ndarray
    flips: np.ndarray
    iterations: np.ndarray
    consistent_states: np.ndarray
    stop: str
    stop_detail: str
    events: list
    solves: int
    halvings: int
    wall_time_s: float
    wall_names: tuple
    rattlers: np.ndarray

    @property
    def reached(self) -> float:
        return float(self.load[-1])


class _Packing:
    """The stepper's own state: configuration, contacts with their tangential forces, loads."""

    def __init__(self, sim: Simulation, targets: Targets):
        snap = sim.snapshot()
        law = snap.law
        if any(snap.periodic):
            raise ParameterError("cell", "periodic", "a box with walls (the stepper does not follow periodic cells)")
        if law.cohesion_force > 0:
            raise ParameterError("cohesion_force", law.cohesion_force,
                                 "0: the stepper follows contacts without cohesion (a distant pair has no status here)")
        if law.rolling_stiffness > 0:
            raise ParameterError("rolling_stiffness", law.rolling_stiffness,
                                 "0: the stepper follows contacts without rolling resistance")
        friction_coefficient("friction", law.friction, slides=True,
                             why="the stepper follows contacts that can slide, on the Coulomb cone")
        self.law = law
        self.n = len(snap.radii)
        self.radii = snap.radii.copy()
        self.x = snap.positions.copy()
        self.angles = snap.angles.copy()
        self.wall_normals = snap.wall_normals.copy()
        self.offsets = snap.wall_offsets.copy()
        self.wall_names = snap.wall_names
        walls = sim.walls
        modes = snap.wall_modes or ("fixed",) * len(self.offsets)
        self.mobile = np.array([m == "force" for m in modes], dtype=bool)
        self.length_ref = walls.length_ref.copy()
        t = sim.time
        self.start_loads = np.array([Load(walls.load[m, 0], walls.load[m, 1], 2 * math.pi / walls.load[m, 2]
                                          if walls.load[m, 2] > 0 else math.inf, walls.load[m, 3]).value(t)
                                     for m in range(len(self.offsets))])
        self.target_loads = self.start_loads.copy()
        for name, value in targets.walls.items():
            if name not in self.wall_names:
                raise ParameterError("wall", name, "one of " + (", ".join(self.wall_names) or "(no walls)"))
            m = self.wall_names.index(name)
            if walls.mode[m] != WALL_FORCE:
                raise ParameterError(f"wall {name!r}", "not force-controlled",
                                     "a wall in force mode (a load moves only a wall free along its normal)")
            self.target_loads[m] = float(value)
        self.start_forces = sim.particles.external_force.copy() + sim.particles.mass[:, None] * np.asarray(sim.gravity)
        self.target_forces = self.start_forces.copy()
        for index, value in targets.forces.items():
            if not 0 <= int(index) < self.n:
                raise ParameterError("disk", index, f"0 <= index < {self.n}")
            self.target_forces[int(index)] += np.asarray(value, dtype=float) - sim.particles.external_force[int(index)]
        p = sim.particles
        fixed = np.zeros(self.dof, dtype=bool)
        kinematic = np.isin(p.kind, (KIND_FIXED, KIND_KINEMATIC))
        fixed[0: 3 * self.n: 3] = (p.inv_mass == 0) | kinematic
        fixed[1: 3 * self.n: 3] = (p.inv_mass == 0) | kinematic
        fixed[2: 3 * self.n: 3] = (p.inv_inertia == 0) | kinematic
        self.free = ~fixed
        c = snap.contacts
        touching = (c.status != 0) & (c.surface_gap <= 0.0)
        self.i, self.j = c.i[touching].astype(np.int64), c.j[touching].astype(np.int64)
        self.ft = c.tangential_force[touching].astype(float)
        self.slid = np.zeros(len(self.i), dtype=bool)
        self.alpha_model = TANGENTIAL[law.tangential_model].alpha_factor
        self.margin = NEAR * float(self.radii.min())
        self.add_near()

    def add_near(self) -> None:
        """Add the pairs and disk-wall pairs closer than ``margin`` that are not candidates yet (without
        force: they touch once their overlap is positive); drop the candidates farther apart."""
        known = set(zip(self.i.tolist(), self.j.tolist())) | set(zip(self.j.tolist(), self.i.tolist()))
        new = []
        if self.n > 1:
            pairs = cKDTree(self.x).query_pairs(2.0 * float(self.radii.max()) + self.margin, output_type="ndarray")
            a, b = pairs[:, 0], pairs[:, 1]
            gap = np.hypot(*(self.x[a] - self.x[b]).T) - self.radii[a] - self.radii[b]
            new += [(max(u, v), min(u, v)) for u, v in pairs[gap < self.margin] if (u, v) not in known]
        for m in range(len(self.offsets)):
            height = self.x @ self.wall_normals[m] - self.offsets[m]
            new += [(u, self.n + m) for u in np.flatnonzero(height - self.radii < self.margin)
                    if (u, self.n + m) not in known]
        new = np.array(new, dtype=np.int64).reshape(-1, 2)
        i, j = np.concatenate([self.i, new[:, 0]]), np.concatenate([self.j, new[:, 1]])
        ft = np.concatenate([self.ft, np.zeros(len(new))])
        slid = np.concatenate([self.slid, np.zeros(len(new), dtype=bool)])
        _, overlap, _, _ = self.geometry(self.x, self.offsets, i, j)
        keep = overlap > -self.margin
        self.i, self.j, self.ft, self.slid = i[keep], j[keep], ft[keep], slid[keep]

    # ------------------------------------------------------------------ loads
    @property
    def dof(self) -> int:
        return 3 * self.n + int(self.mobile.sum())

    def wall_load(self, lam: float, offsets) -> np.ndarray:
        """The walls' loads at ``lam``: a load per length times the box length it spans at ``offsets``."""
        sigma = self.start_loads + lam * (self.target_loads - self.start_loads)
        out = sigma.copy()
        for m, (a, b) in enumerate(self.length_ref):
            if a >= 0:
                out[m] = sigma[m] * -(offsets[a] + offsets[b])
        return out

    def external(self, lam: float, offsets=None) -> np.ndarray:
        """The load on every velocity component at ``lam``, the walls at ``offsets`` (default: the present)."""
        out = np.zeros(self.dof)
        forces = self.start_forces + lam * (self.target_forces - self.start_forces)
        out[0: 3 * self.n: 3] = forces[:, 0]
        out[1: 3 * self.n: 3] = forces[:, 1]
        out[3 * self.n:] = self.wall_load(lam, self.offsets if offsets is None else offsets)[self.mobile]
        return out

    def rattlers(self, net: stiffness.Network) -> np.ndarray:
        """Disks with fewer than two touching contacts and no force of their own: they carry none."""
        touching = net.kn > 0.0
        count = np.bincount(net.first[touching], minlength=self.n) + \
            np.bincount(net.second[touching & (net.second >= 0)], minlength=self.n)
        loaded = np.any(self.start_forces != 0.0, axis=1) | np.any(self.target_forces != 0.0, axis=1)
        return (count < 2) & ~loaded

    # ------------------------------------------------------------------ geometry and forces
    def geometry(self, x, offsets, i, j):
        """Normal (M, 2), overlap (M,), distance of centres (M,) and wall flags of contacts ``i, j``."""
        is_wall = j >= self.n
        jj = np.where(is_wall, 0, j)
        branch = x[i] - x[jj]
        distance = np.hypot(branch[:, 0], branch[:, 1])
        m = np.where(is_wall, j - self.n, 0)
        wn = self.wall_normals[m] if len(self.wall_normals) else np.zeros((len(i), 2))
        height = np.einsum("ij,ij->i", x[i], wn) - (offsets[m] if len(offsets) else 0.0)
        normal = np.where(is_wall[:, None], wn, branch / np.maximum(distance, 1e-300)[:, None])
        ri = self.radii[i]
        rj = np.where(is_wall, 0.0, self.radii[jj])
        overlap = np.where(is_wall, ri - height, ri + rj - distance)
        return normal, overlap, np.where(is_wall, height, distance), is_wall

    def elastic_normal(self, overlap, i, j, is_wall) -> np.ndarray:
        ri = self.radii[i]
        rj = np.where(is_wall, 0.0, self.radii[np.where(is_wall, 0, j)])
        return normal_laws.forces(NORMAL[self.law.normal_model].code, float(self.law.normal_stiffness),
                                  *stiffness.rows(overlap, ri, rj, is_wall))

    def network(self, x, offsets, i, j, ne, ft, status, lam) -> stiffness.Network:
        normal, overlap, distance, is_wall = self.geometry(x, offsets, i, j)
        ri = self.radii[i]
        rj = np.where(is_wall, 0.0, self.radii[np.where(is_wall, 0, j)])
        alpha = np.where(is_wall, 1.0, (ri + rj) / np.maximum(distance, 1e-300)) if self.alpha_model \
            else np.ones(len(i))
        touching = overlap > 0.0
        kn = np.where(touching, stiffness.tangent_normal_stiffness(self.law, np.maximum(overlap, 0.0), ri, rj,
                                                                    is_wall), 0.0)
        kt = np.where(touching & (self.law.friction > 0.0), self.law.tangential_stiffness, 0.0)
        mobile = self.mobile
        wall_dof = np.full(len(offsets), -1)
        wall_dof[mobile] = 3 * self.n + np.arange(int(mobile.sum()))
        branch = np.zeros((len(i), 2))
        return stiffness.Network(x, self.radii, i, np.where(is_wall, -1, j), np.where(is_wall, j - self.n, -1),
                                 normal, alpha, kn, kt, np.zeros(len(i)), status, ne, ft, float(self.law.friction),
                                 self.wall_normals, wall_dof, self.external(lam, offsets), branch, np.zeros(2),
                                 np.full(2, -1), ~self.free)


class _Stepper:
    def __init__(self, packing: _Packing, tolerance: float, check_unique: bool):
        self.p = packing
        self.tolerance = tolerance
        self.check_unique = check_unique
        self.solves = 0
        self.events = []
        self._start = None

    def begin(self, lam: float):
        """Start a step at the present state: its network and out-of-balance force at load ``lam``."""
        p = self.p
        self.x0, self.angles0, self.offsets0 = p.x.copy(), p.angles.copy(), p.offsets.copy()
        self._start = None
        net, _, residual = self.forces(np.zeros(p.dof), p.i, p.j, p.ft, lam)
        # the contacts that slid in the last step start minimum sliding as sliding: one flip per change
        still = p.slid & (np.abs(net.tangential) >= p.law.friction * net.elastic_normal) & (net.elastic_normal > 0)
        status = np.where(still, np.where(net.tangential > 0, STATUS_SLIDE_POS, STATUS_SLIDE_NEG), net.status)
        return replace(net, status=status), residual

    def moved(self, du):
        """Positions, angles and wall offsets after the displacements ``du`` from the step's start."""
        p = self.p
        x = self.x0 + np.column_stack([du[0: 3 * p.n: 3], du[1: 3 * p.n: 3]])
        angles = self.angles0 + du[2: 3 * p.n: 3] / p.radii
        offsets = self.offsets0.copy()
        offsets[p.mobile] += du[3 * p.n:]
        return x, angles, offsets

    def forces(self, du, i, j, ft0, lam):
        """The contacts' forces and statuses at ``du`` from the step's start, with the residual."""
        p = self.p
        x, _, offsets = self.moved(du)
        _, overlap, _, is_wall = p.geometry(x, offsets, i, j)
        ne = p.elastic_normal(overlap, i, j, is_wall)
        kt = np.where((overlap > 0.0) & (p.law.friction > 0.0), p.law.tangential_stiffness, 0.0)
        rel = stiffness.relative_velocities(self.start_network(i, j, ft0, lam), du) if len(i) else np.zeros((0, 3))
        ft = ft0 - kt * rel[:, 1]
        limit = p.law.friction * ne
        status = np.where(ft > limit, STATUS_SLIDE_POS, np.where(ft < -limit, STATUS_SLIDE_NEG, STATUS_STICK))
        ft = np.clip(ft, -limit, limit)
        net = p.network(x, offsets, i, j, ne, ft, status, lam)
        c = stiffness.compatibility(net, (stiffness.NORMAL, stiffness.TANGENTIAL))
        residual = net.external + c @ np.column_stack([ne, ft]).ravel()
        return net, overlap, residual

    def start_network(self, i, j, ft0, lam):
        """The network at the step's start (the compatibility of the step's displacements)."""
        if self._start is None:
            p = self.p
            normal, overlap, _, is_wall = p.geometry(self.x0, self.offsets0, i, j)
            ne = p.elastic_normal(overlap, i, j, is_wall)
            self._start = p.network(self.x0, self.offsets0, i, j, ne, ft0, np.full(len(i), STATUS_STICK), lam)
        return self._start

    def scale(self, ne) -> float:
        positive = ne[ne > 0]
        if positive.size:
            return float(positive.mean())
        loads = np.abs(self.p.external(1.0))
        return float(loads.max()) if loads.size and loads.max() > 0 else 1.0

    def solve(self, net, rhs, sliding):
        """du of k du = rhs on the free degrees of freedom, and the relative residual of that solve."""
        self.solves += 1
        free = self.p.free
        k = stiffness.stiffness_matrix(net, sliding).tocsr()[free][:, free]
        du = np.zeros(net.dof)
        du[free] = stiffness.regularised_solve(k, rhs[free])
        norm = float(np.abs(rhs[free]).max(initial=0.0))
        miss = float(np.abs(k @ du[free] - rhs[free]).max(initial=0.0)) / norm if norm > 0 else 0.0
        return du, miss

    def step(self, lam0: float, lam1: float):
        """One step from λ0 to λ1: (ok, reason, detail, record)."""
        p = self.p
        i, j, ft0 = p.i, p.j, p.ft
        net0, residual0 = self.begin(lam0)
        increment = p.external(lam1) - p.external(lam0)
        critical = critical_contacts(net0)
        record = {"critical": len(critical), "flips": 0, "consistent_states": -1}
        if len(i):
            try:
                solution = solve_status(net0, increment, critical)
            except ParameterError as error:
                return False, "no_status", f"at load fraction {lam0:.6g}: {error}", record
            self.solves += solution.iterations + 1
            record["flips"] = solution.iterations
            sliding = solution.sliding
            if self.check_unique and 0 < len(critical) <= (MAX_UNIQUE if net0.dof <= stiffness.DENSE_SIZE
                                                           else MAX_ENUMERATED_SPARSE):
                record["consistent_states"] = len(enumerate_states(net0, increment, critical).consistent_states)
            if self._unstable(net0, sliding):
                return False, "unstable", f"k of the consistent status has a direction of negative Q at load " \
                                          f"fraction {lam0:.6g}", record
        else:
            sliding = np.zeros(0, dtype=bool)
        du, miss = self.solve(net0, increment + residual0, sliding)
        if miss > 1e-6:
            return False, "collapse", f"the load increment at load fraction {lam0:.6g} excites a mechanism " \
                                      f"(|k du - df| / |df| = {miss:.2g})" + self.sliding_text(sliding), record
        limit = MAX_MOVE * float(p.radii.min())
        for iteration in range(1, MAX_ITERATIONS + 1):
            if np.abs(du).max() > limit * 1e3:
                return False, "collapse", f"the packing gives way past load fraction {lam0:.6g}", record
            net, overlap, residual = self.forces(du, i, j, ft0, lam1)
            scale = self.scale(net.elastic_normal)
            if np.abs(residual[p.free]).max() <= self.tolerance * scale:
                record["iterations"] = iteration
                moved = np.abs(du).max()
                if moved > limit:
                    return False, "collapse", f"a step of {moved:.3g} (more than {MAX_MOVE:g} of the smallest " \
                                              f"radius) past load fraction {lam0:.6g}", record
                return True, "", "", (record, du, net, overlap)
            correction, miss = self.solve(net, residual, net.sliding)
            if miss > 1e-6:
                return False, "collapse", f"between load fractions {lam0:.6g} and {lam1:.6g}" + \
                    self.sliding_text(net.sliding), record
            du = du + correction
        return False, "collapse", f"Newton's iterations do not converge between load fractions {lam0:.6g} and " \
                                  f"{lam1:.6g}", record

    def sliding_text(self, sliding) -> str:
        """", contacts 3–7, 5–wall 'floor' sliding" (at most four named)."""
        rows = np.flatnonzero(sliding)
        if not len(rows):
            return ""
        names = [self.name(self.p.i[a], self.p.j[a]) for a in rows[:4]]
        more = f" and {len(rows) - 4} more" if len(rows) > 4 else ""
        return f", contact{'s' if len(rows) > 1 else ''} {', '.join(names)}{more} sliding"

    def _unstable(self, net, sliding) -> bool:
        """Whether the symmetric part of k(consistent status) has a negative eigenvalue on the free
        degrees of freedom of the disks that carry force (quasi-rigidity Eqs. 41-45): a rattler
        touched by one contact at the corrector's tolerance has a direction of negative Q of its own."""
        k = stiffness.stiffness_matrix(net, sliding)
        keep = self.p.free.copy()
        for offset in range(3):
            keep[3 * np.flatnonzero(self.p.rattlers(net)) + offset] = False
        index = np.flatnonzero(keep)
        sym = ((k + k.T) * 0.5).tocsr()[index][:, index]
        scale = float(np.abs(sym.diagonal()).max()) if len(index) else 0.0
        return scale > 0 and stiffness.count_below(sym.tocsc(), -stiffness.ZERO_TOLERANCE * scale,
                                                   stiffness.SOLVE_DENSE_SIZE) > 0

    def accept(self, du, net, overlap, lam) -> None:
        """Take the converged step, naming the contacts that opened or closed in it (not those of a
        rattler: one touched at the corrector's tolerance carries no force either way)."""
        p = self.p
        start = self.start_network(p.i, p.j, p.ft, lam)
        before, after = start.kn > 0.0, overlap > 0.0
        idle = p.rattlers(start) | p.rattlers(net)
        for a in np.flatnonzero((before != after) & ~idle[p.i] & ~(idle[np.minimum(p.j, p.n - 1)] & (p.j < p.n))):
            self.events.append((lam, "closed" if after[a] else "opened", self.name(p.i[a], p.j[a])))
        p.x, p.angles, p.offsets = self.moved(du)
        p.ft = net.tangential.copy()
        p.slid = net.sliding.copy()
        p.add_near()

    def changes_within(self, lam0: float, lam1: float) -> list[str]:
        """The contacts that open or close on the way from ``lam0`` to ``lam1`` (the linear step,
        unless it moves more than :data:`MAX_MOVE`): "contact 3–7 opens" (at most four named)."""
        p = self.p
        net0, residual0 = self.begin(lam0)
        du, _ = self.solve(net0, p.external(lam1) - p.external(lam0) + residual0, net0.sliding)
        if np.abs(du).max() > MAX_MOVE * float(p.radii.min()):  # the packing gives way: a collapse
            return []
        x, _, offsets = self.moved(du)
        _, overlap, _, _ = p.geometry(x, offsets, p.i, p.j)
        changed = np.flatnonzero((overlap > 0.0) != (net0.kn > 0.0))
        names = [f"contact {self.name(p.i[a], p.j[a])} {'closes' if overlap[a] > 0.0 else 'opens'}"
                 for a in changed[:4]]
        return names + ([f"{len(changed) - 4} more"] if len(changed) > 4 else [])

    def name(self, a, b) -> str:
        p = self.p
        return f"{a}–{b}" if b < p.n else f"{a}–wall '{p.wall_names[b - p.n]}'"


def follow(sim: Simulation, targets: Targets, steps: int = 100, tolerance: float = TOLERANCE,
           max_halvings: int = 12, check_unique: bool = False) -> QuasiStaticPath:
    """Follow the load from its present value to ``targets`` in ``steps`` equal steps of λ (halved
    where a step does not converge). ``sim`` must hold a packing in equilibrium; it is not changed."""
    start = time.perf_counter()
    if int(steps) != steps or not 1 <= steps <= MAX_STEPS:
        raise ParameterError("steps", steps, f"a whole number from 1 to {MAX_STEPS} (a 400-disk box takes about "
                                             f"0.1 s a step)")
    packing = _Packing(sim, targets)
    stepper = _Stepper(packing, tolerance, check_unique)
    rows = {key: [] for key in ("load", "wall_offsets", "positions", "angles", "sliding", "critical", "flips",
                                "iterations", "consistent_states")}

    def keep(lam, record, sliding):
        rows["load"].append(lam)
        rows["wall_offsets"].append(packing.offsets.copy())
        rows["positions"].append(packing.x.copy())
        rows["angles"].append(packing.angles.copy())
        rows["sliding"].append(sliding)
        for key in ("critical", "flips", "iterations", "consistent_states"):
            rows[key].append(record.get(key, 0))

    keep(0.0, {"consistent_states": -1}, len(critical_contacts(stepper.begin(0.0)[0])))
    lam, nominal = 0.0, 1.0 / steps
    size, halvings, stop, detail = nominal, 0, "target", STOP_REASONS["target"]
    while lam < 1.0 - 1e-12:
        target = min(1.0, lam + size)
        ok, reason, why, outcome = stepper.step(lam, target)
        if not ok:
            if size <= nominal / 2 ** max_halvings:
                stop, detail = reason, why
                changes = stepper.changes_within(lam, target) if reason == "collapse" else []
                if changes:
                    stop, detail = "network", f"{why}, {', '.join(changes)}"
                break
            size /= 2.0
            halvings += 1
            continue
        record, du, net, overlap = outcome
        lam = target
        stepper.accept(du, net, overlap, lam)
        keep(lam, record, int(np.count_nonzero(net.sliding)))
        size = min(nominal, 2.0 * size)
    return QuasiStaticPath(**{key: np.array(value) for key, value in rows.items()}, stop=stop, stop_detail=detail,
                           events=stepper.events, solves=stepper.solves, halvings=halvings,
                           wall_time_s=time.perf_counter() - start, wall_names=packing.wall_names,
                           rattlers=packing.rattlers(stepper.begin(lam)[0]))


@dataclass(frozen=True)
class DynamicPath:
    """The end of the same load change ramped in the dynamics over ``duration``: disk positions and
    angles, wall offsets, the steps it took and their wall time."""

    duration: float
    positions: np.ndarray
    angles: np.ndarray
    wall_offsets: np.ndarray
    steps: int
    wall_time_s: float


RAMP_UPDATES = 2000
"""Times the forces on disks are updated along a dynamic ramp (the walls' loads follow it each step)."""


def follow_dynamically(sim: Simulation, targets: Targets, duration: float) -> DynamicPath:
    """Ramp the loads of ``targets`` in a copy of ``sim`` from their present values over ``duration``,
    smoothly (``(1 - cos(pi t / duration)) / 2``: no jolt at either end), and return its end. The
    quasi-static path does not depend on how the load is timed, only on its values."""
    start = time.perf_counter()
    duration = float(duration)
    if not duration > 0 or not math.isfinite(duration):
        raise ParameterError("duration", duration, "a time > 0")
    packing = _Packing(sim, targets)
    dyn = sim.clone()
    t0 = dyn.time
    omega = math.pi / duration
    for m, name in enumerate(packing.wall_names):
        if packing.target_loads[m] != packing.start_loads[m]:
            dyn.set_wall_load(name, Load(base=packing.start_loads[m],
                                         amplitude=(packing.target_loads[m] - packing.start_loads[m]) / 2.0,
                                         period=2.0 * duration, phase=-omega * t0))
    steps = max(1, int(round(duration / dyn.dt)))
    forces_change = np.flatnonzero(np.any(packing.target_forces != packing.start_forces, axis=1))
    base = dyn.particles.external_force.copy()
    change = packing.target_forces - packing.start_forces
    chunk = max(1, steps // RAMP_UPDATES) if len(forces_change) else steps
    done = 0
    try:
        while done < steps:
            n = min(chunk, steps - done)
            if len(forces_change):
                share = 0.5 * (1.0 - math.cos(omega * (done + n) * dyn.dt))  # the last chunk at the target
                dyn.particles.external_force[forces_change] = base[forces_change] + share * change[forces_change]
            dyn.run(n)
            done += n
    except DivergenceError as error:
        raise GranLabError(f"the dynamics diverged while ramping the load over {duration:g}: {error}") from error
    snap = dyn.snapshot()
    return DynamicPath(duration, snap.positions, snap.angles, snap.wall_offsets, steps, time.perf_counter() - start)


def difference(path: QuasiStaticPath, dynamic: DynamicPath, mobile) -> dict:
    """How far the dynamics' end is from the quasi-static one: the RMS difference of the displacements
    of the disks that carry force (the rattlers wander in the dynamics) and of the force-controlled
    walls, each over the quasi-static RMS displacement."""
    carry = ~path.rattlers
    moved = path.positions[-1][carry] - path.positions[0][carry]
    disks = float(np.sqrt(np.mean((dynamic.positions[carry] - path.positions[-1][carry]) ** 2)) /
                  max(np.sqrt(np.mean(moved ** 2)), 1e-300))
    mobile = np.asarray(mobile, dtype=bool)
    walls = None
    if mobile.any():
        wall_moved = path.wall_offsets[-1][mobile] - path.wall_offsets[0][mobile]
        walls = float(np.sqrt(np.mean((dynamic.wall_offsets[mobile] - path.wall_offsets[-1][mobile]) ** 2)) /
                      max(np.sqrt(np.mean(wall_moved ** 2)), 1e-300))
    return {"duration": dynamic.duration, "steps": dynamic.steps, "wall_time_s": dynamic.wall_time_s,
            "disks": disks, "walls": walls}


START_TOLERANCE = 1e-3
"""Largest out-of-balance force a start may have, as a fraction of its mean normal force."""


def out_of_balance(sim: Simulation) -> float:
    """The largest out-of-balance force on a free degree of freedom of ``sim``'s present state (its
    contact forces at rest against its loads), over the mean normal force."""
    packing = _Packing(sim, Targets())
    stepper = _Stepper(packing, TOLERANCE, False)
    net, residual = stepper.begin(0.0)
    return float(np.abs(residual[packing.free]).max(initial=0.0)) / stepper.scale(net.elastic_normal)


def scaled(sim: Simulation, targets: Targets, share: float) -> Targets:
    """The loads a share of the way from the present ones to ``targets``."""
    packing = _Packing(sim, targets)
    walls = {name: packing.start_loads[packing.wall_names.index(name)] * (1.0 - share) + share * value
             for name, value in targets.walls.items()}
    external = sim.particles.external_force
    forces = {i: tuple(external[int(i)] * (1.0 - share) + share * np.asarray(value, dtype=float))
              for i, value in targets.forces.items()}
    return Targets(walls, forces)


def compare(sim: Simulation, targets: Targets, steps: int = 100, durations=(), check_unique: bool = False) -> dict:
    """:func:`follow` the load, then ramp the load it reached in the dynamics over each of
    ``durations`` and measure how far each end is from the quasi-static one (:func:`difference`).
    Refuses a start out of balance by more than :data:`START_TOLERANCE`."""
    imbalance = out_of_balance(sim)
    if imbalance > START_TOLERANCE:
        raise GranLabError(f"the start is not in equilibrium: its largest out-of-balance force is {imbalance:.3g} of "
                           f"the mean normal force (at most {START_TOLERANCE:g}); let it settle first (a longer "
                           f"scene, or granlab prepare ... --out FILE)")
    path = follow(sim, targets, steps, check_unique=check_unique)
    packing = _Packing(sim, targets)
    overlap = packing.geometry(packing.x, packing.offsets, packing.i, packing.j)[1]
    reached = scaled(sim, targets, path.reached)
    comparisons = [difference(path, follow_dynamically(sim, reached, duration), packing.mobile)
                   for duration in durations]
    return {"path": path, "start_imbalance": imbalance, "mobile": packing.mobile, "comparisons": comparisons,
            "start_loads": packing.start_loads, "target_loads": packing.target_loads, "disks": packing.n,
            "contacts": int(np.count_nonzero(overlap > 0))}
