"""The stiffness matrix of a packing and its null space (quasi-rigidity Secs. II-III; ratcheting
App. A; Gilabert App. A).

Bodies and their velocities (quasi-rigidity Eq. 15): each disk i has ``(v_x, v_y, r_i w_i)``; each
wall in force mode (a wall pushed by a load, free along its normal) has one, its velocity along its
normal; each axis of a periodic cell under stress control (Gilabert Eq. 3) has one, the rate
``dL_a/dt`` of its length (the cell's "two strain degrees of freedom", Gilabert App. A: N_f = 3N + 2).
Fixed and velocity-driven walls, and fixed or strain-rate-driven axes, are supports, not bodies.

Disk velocities are those relative to the cell's affine motion (as in the engine): a contact
through the cell has ``V = v_i - v_j + (dL/dt / L) r`` per axis, so the column of axis a holds
``n_a r_a / L_a`` (normal) and ``alpha t_a r_a / L_a`` (tangential), and the force conjugate to
``dL_a/dt`` is ``sum_c f_a r_a / L_a = sigma^I_aa A / L_a`` (the contact virial, compression
positive). Its load is ``-sigma^M_aa A / L_a``, the target stress pressing the cell in. Wall
contacts do not deform with the cell. The terms of the pre-stress (the turn of n, and A changing
with L) are left out here as for the disks: they are of order N^e/(K_n r) against those kept.

Contacts follow the engine's conventions (:mod:`granlab.engine.kernels.laws`, :mod:`granlab.engine.kernels.contacts`):
``n`` points from j to i (from a wall into its disk), ``t = z × n``, ``F_n > 0`` repels,
``V_n = (v_i - v_j)·n`` and ``V_t = alpha (v_i - v_j)·t - r_i w_i - r_j w_j`` (``alpha = 1`` for the
Cundall-Strack spring, ``(r_i + r_j)/|r_ij|`` for the alpha-corrected and angle-based ones,
ratcheting Eqs. 24-25), the torque of ``F_t`` on either disk ``-r F_t``. So the block of c for
contact alpha and its first body i (quasi-rigidity Eq. 18) is

    ( n_x   alpha t_x )
    ( n_y   alpha t_y )
    ( 0        -1     )

and minus the translational rows, with the same last row, for its second body; a wall's single
entry is ``(-1, 0)`` (it receives ``-F_n`` along its normal). A rolling spring (Gilabert Eq. 10) adds a
third component per contact, the relative rotation ``w_i - w_j``, whose entries in the third rows are
``1/r_i`` and ``-1/r_j`` (the moment over the radius).

The contact stiffnesses are tangent ones: ``K_n = dN^e/d(-D_n)`` (``k_n`` for the linear law,
``k_n chord / l`` for the area law), ``K_t = k_t``, ``K_r = k_r``; a distant cohesive pair has only a
normal one, ``-F0/D0`` (Gilabert App. A). For a sliding contact the status matrix of quasi-rigidity
Eq. 24 makes ``dF_t = -sgn(D_t) mu dN^e``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import params
from ..errors import GranLabError, ParameterError
from ..kernels import normal as normal_laws
from ..observables import interacting, sliding
from ..state import STATUS_COHESIVE
from . import LOADS
from .report import AnalysisReport, Clock
from .states import require_forces

LABELS = {
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
}
"""The label of each value of the stiffness analysis (:func:`run`)."""
NORMAL, TANGENTIAL, ROLLING = 0, 1, 2
ZERO_TOLERANCE = 1e-9
"""Eigenvalues below this fraction of the largest diagonal entry count as zero (null modes)."""
DENSE_SIZE = 1500
"""Matrices up to this order are factorised dense (LAPACK), larger ones sparse (SuperLU, ARPACK)."""
SOLVE_DENSE_SIZE = 200
"""Linear systems up to this order are solved dense; larger ones sparse (SuperLU): at 1202 (400
disks in a box) 12 against 160 ms, the same solution within 2e-14."""


@dataclass(frozen=True)
class Network:
    """The contacts of one state as the matrices need them (M rows, disks first then walls).

    ``first (M,)`` disk i; ``second (M,)`` disk j or -1 for a wall; ``wall (M,)`` the wall's index or
    -1; ``normal (M, 2)``; ``alpha (M,)``; ``kn, kt, kr (M,)`` tangent stiffnesses; ``status (M,)``;
    ``elastic_normal (M,)`` N^e; ``tangential (M,)`` F_t; ``wall_dof (W,)`` the velocity index of
    each wall (-1 for a support); ``external (n_dof,)`` the load on each velocity component;
    ``branch (M, 2)`` r = x_i - x_j - image L (for a wall: zero, it does not deform with the cell);
    ``cell_lengths (2,)``; ``cell_dof (2,)`` the velocity index of each axis of the cell (-1 unless
    under stress control); ``fixed (n_dof,)`` the velocity components held at zero (a disk of
    infinite mass or inertia, in the quasi-static stepper), or None: every one is free.
    """

    positions: np.ndarray
    radii: np.ndarray
    first: np.ndarray
    second: np.ndarray
    wall: np.ndarray
    normal: np.ndarray
    alpha: np.ndarray
    kn: np.ndarray
    kt: np.ndarray
    kr: np.ndarray
    status: np.ndarray
    elastic_normal: np.ndarray
    tangential: np.ndarray
    friction: float
    wall_normals: np.ndarray
    wall_dof: np.ndarray
    external: np.ndarray
    branch: np.ndarray
    cell_lengths: np.ndarray
    cell_dof: np.ndarray
    fixed: np.ndarray | None = None

    @property
    def disks(self) -> int:
        return int(self.radii.shape[0])

    @property
    def contacts(self) -> int:
        return int(self.first.shape[0])

    @property
    def dof(self) -> int:
        return 3 * self.disks + int(np.count_nonzero(self.wall_dof >= 0)) + int(np.count_nonzero(self.cell_dof >= 0))

    @property
    def distant(self) -> np.ndarray:
        return self.status == STATUS_COHESIVE

    @property
    def sliding(self) -> np.ndarray:
        """The contacts the dynamics left sliding (on the Coulomb cone)."""
        return sliding(self.status)

    @property
    def sign_dt(self) -> np.ndarray:
        """sgn D_t = -sgn F_t (F_t = -K_t D_t); +1 where F_t = 0."""
        return np.where(self.tangential > 0.0, -1.0, 1.0)


def tangent_normal_stiffness(law, overlap, ri, rj, is_wall) -> np.ndarray:
    """dN^e / d overlap of each contact: its normal law's tangent stiffness (``K_n`` for the linear
    law, ``K_n chord / l`` for the area law: dA/d overlap is the chord)."""
    return normal_laws.stiffnesses(params.NORMAL[law.normal_model].code, float(law.normal_stiffness),
                                   *rows(overlap, ri, rj, is_wall))


def rows(overlap, ri, rj, is_wall) -> tuple[np.ndarray, ...]:
    """Columns of contacts as the normal laws' row kernels take them (float, float, float, bool)."""
    columns = (np.ascontiguousarray(a, dtype=float) for a in (overlap, ri, rj))
    return (*columns, np.ascontiguousarray(is_wall, dtype=bool))


def network(snapshot, cell_lengths=None) -> Network:
    """The :class:`Network` of an :class:`granlab.engine.simulation.Snapshot`.

    Force-mode walls are bodies; their load is taken as what balances the disks' push
    (``-wall_forces``), the load of a packing in equilibrium.
    """
    c = snapshot.contacts
    law = snapshot.law
    n = len(snapshot.radii)
    keep = interacting(c.status)
    i, j, image = c.i[keep], c.j[keep], c.image[keep]
    is_wall = j >= n
    wall = np.where(is_wall, j - n, -1)
    second = np.where(is_wall, -1, j)
    jj = np.where(is_wall, 0, j)
    cell = np.where(np.array(snapshot.periodic), snapshot.cell_lengths, 0.0) if cell_lengths is None else cell_lengths
    branch = snapshot.positions[i] - snapshot.positions[jj] - image * cell
    distance = np.hypot(branch[:, 0], branch[:, 1])
    normal = np.where(is_wall[:, None], snapshot.wall_normals[np.maximum(wall, 0)] if len(snapshot.wall_normals)
                      else 0.0, branch / np.maximum(distance, 1e-300)[:, None])
    ri, rj = snapshot.radii[i], np.where(is_wall, 0.0, snapshot.radii[jj])
    alpha = np.where(is_wall, 1.0, (ri + rj) / np.maximum(distance, 1e-300)) \
        if params.TANGENTIAL[law.tangential_model].alpha_factor else np.ones(len(i))
    gap = c.surface_gap[keep]
    status = c.status[keep]
    distant = status == STATUS_COHESIVE
    kn = np.where(distant, -law.cohesion_force / law.cohesion_range if law.cohesion_range > 0 else 0.0,
                  tangent_normal_stiffness(law, np.maximum(-gap, 0.0), ri, rj, is_wall))
    # a frictionless contact (mu = 0) carries no tangential force whatever the motion
    kt = np.where(distant | (law.friction == 0.0), 0.0, law.tangential_stiffness)
    kr = np.where(distant, 0.0, law.rolling_stiffness)
    modes = snapshot.wall_modes or ("fixed",) * len(snapshot.wall_normals)
    mobile = np.array([m == "force" for m in modes], dtype=bool)
    wall_dof = np.full(len(modes), -1)
    wall_dof[mobile] = 3 * n + np.arange(int(mobile.sum()))
    controlled = np.array([c == "stress" for c in snapshot.cell_control] or [False, False])
    cell_dof = np.full(2, -1)
    cell_dof[controlled] = 3 * n + int(mobile.sum()) + np.arange(int(controlled.sum()))
    lengths = np.asarray(snapshot.cell_lengths, dtype=float)
    external = np.zeros(3 * n + int(mobile.sum()) + int(controlled.sum()))
    external[wall_dof[mobile]] = -np.asarray(snapshot.wall_forces)[mobile]
    if controlled.any():
        area = float(np.prod(snapshot.box_lengths))
        target = np.asarray(snapshot.cell_target_stress, dtype=float)
        external[cell_dof[controlled]] = -target[controlled] * area / lengths[controlled]
    return Network(snapshot.positions, snapshot.radii, i, second, wall, normal, alpha, kn, kt, kr, status,
                   c.elastic_normal_force[keep], c.tangential_force[keep], float(law.friction),
                   np.asarray(snapshot.wall_normals), wall_dof, external, np.where(is_wall[:, None], 0.0, branch),
                   lengths, cell_dof)


def compatibility(net: Network, components=(NORMAL, TANGENTIAL)) -> sp.csr_matrix:
    """c (n_dof × len(components) M): column ``len(components) alpha + k`` is component
    ``components[k]`` of contact alpha (quasi-rigidity Eqs. 17-19; cᵀ maps velocities to the
    relative velocities V, Eq. 23)."""
    m, width = net.contacts, len(components)
    rows, cols, values = [], [], []
    idx = np.arange(m)
    i, j, wall = net.first, net.second, net.wall
    pair = j >= 0
    tx, ty = -net.normal[:, 1], net.normal[:, 0]
    for k, component in enumerate(components):
        col = width * idx + k
        if component == NORMAL:
            entries = [(3 * i, net.normal[:, 0]), (3 * i + 1, net.normal[:, 1])]
            rows += [3 * j[pair], 3 * j[pair] + 1]
            cols += [col[pair]] * 2
            values += [-net.normal[pair, 0], -net.normal[pair, 1]]
            walls = ~pair & (net.wall_dof[np.maximum(wall, 0)] >= 0) if len(net.wall_dof) else np.zeros(m, bool)
            rows.append(net.wall_dof[wall[walls]])
            cols.append(col[walls])
            values.append(-np.ones(int(walls.sum())))
        elif component == TANGENTIAL:
            entries = [(3 * i, net.alpha * tx), (3 * i + 1, net.alpha * ty), (3 * i + 2, -np.ones(m))]
            rows += [3 * j[pair], 3 * j[pair] + 1, 3 * j[pair] + 2]
            cols += [col[pair]] * 3
            values += [-(net.alpha * tx)[pair], -(net.alpha * ty)[pair], -np.ones(int(pair.sum()))]
        elif component == ROLLING:
            entries = [(3 * i + 2, 1.0 / net.radii[i])]
            rows.append(3 * j[pair] + 2)
            cols.append(col[pair])
            values.append(-1.0 / net.radii[j[pair]])
        else:
            raise ParameterError("contact component", component, "NORMAL, TANGENTIAL or ROLLING")
        if component in (NORMAL, TANGENTIAL):  # the cell's strain rates deform r
            along = net.normal if component == NORMAL else net.alpha[:, None] * np.column_stack([tx, ty])
            for axis in np.flatnonzero(net.cell_dof >= 0):
                entries.append((np.full(m, net.cell_dof[axis]), along[:, axis] * net.branch[:, axis]
                                / net.cell_lengths[axis]))
        for r, v in entries:
            rows.append(r)
            cols.append(col)
            values.append(v)
    return sp.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(net.dof, width * m))


def components(net: Network) -> tuple[int, ...]:
    """The relative motions that carry forces: normal always, tangential with friction, rolling
    with a rolling spring (Gilabert App. A)."""
    out = (NORMAL,)
    if net.friction > 0.0 and np.any(net.kt > 0.0):
        out += (TANGENTIAL,)
    if np.any(net.kr > 0.0):
        out += (ROLLING,)
    return out


def stiffness_matrix(net: Network, sliding: np.ndarray | None = None) -> sp.csr_matrix:
    """k = c K S(𝕊) cᵀ (quasi-rigidity Eqs. 21-25, 30), n_dof × n_dof, for the sliding set
    ``sliding`` (M booleans; default: the statuses the dynamics left). The force increment on the
    bodies for velocities v is ``-k v`` and the quasi-static balance is ``df_ext/dt = k v`` (Eq. 39)."""
    sliding = net.sliding if sliding is None else np.asarray(sliding, dtype=bool)
    if sliding.shape != (net.contacts,):
        raise ParameterError("sliding", f"shape {sliding.shape}", f"{net.contacts} booleans, one per contact")
    comps = (NORMAL, TANGENTIAL, ROLLING)
    c = compatibility(net, comps)
    m = net.contacts
    idx = 3 * np.arange(m)
    sticking = ~sliding & ~net.distant
    # K S per contact: rows (normal, tangential, rolling) of dF = -(K S) V
    rows = [idx, idx + 1, idx + 2]
    cols = [idx, idx + 1, idx + 2]
    values = [net.kn, np.where(sticking, net.kt, 0.0), net.kr]
    slide = np.flatnonzero(sliding)
    rows.append(idx[slide] + 1)
    cols.append(idx[slide])
    values.append(-net.friction * net.kn[slide] * net.sign_dt[slide])
    ks = sp.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * m, 3 * m))
    return (c @ ks @ c.T).tocsr()


def relative_velocities(net: Network, v: np.ndarray) -> np.ndarray:
    """V = cᵀ v as (M, 3): normal, tangential and rolling components (quasi-rigidity Eq. 23)."""
    return (compatibility(net, (NORMAL, TANGENTIAL, ROLLING)).T @ v).reshape(-1, 3)


def quadratic_form(net: Network, v: np.ndarray, sliding: np.ndarray | None = None) -> float:
    """Q(v, 𝕊) = vᵀ k v as the contact sum of quasi-rigidity Eqs. 43-45 (plus K_r V_r² per
    rolling spring)."""
    sliding = net.sliding if sliding is None else np.asarray(sliding, dtype=bool)
    rel = relative_velocities(net, v)
    vn, vt, vr = rel[:, 0], rel[:, 1], rel[:, 2]
    stick = net.kn * vn ** 2 + np.where(net.distant, 0.0, net.kt) * vt ** 2
    slide = net.kn * vn ** 2 - net.friction * net.kn * vt * vn * net.sign_dt
    return float(np.sum(np.where(sliding, slide, stick) + net.kr * vr ** 2))


def count_below(matrix: sp.spmatrix, threshold: float, dense_size: int = DENSE_SIZE) -> int:
    """Number of eigenvalues of the symmetric ``matrix`` below ``threshold`` (Sylvester's law of
    inertia: the negative pivots of an LDLᵀ factorisation of ``matrix - threshold I``, taken from a
    sparse LU with symmetric ordering and diagonal pivots; up to ``dense_size``, its eigenvalues)."""
    n = matrix.shape[0]
    if n == 0:
        return 0
    if n <= dense_size:
        return int(np.count_nonzero(np.linalg.eigvalsh(matrix.toarray()) < threshold))
    shifted = (matrix - threshold * sp.identity(n, format="csc")).tocsc()
    lu = spla.splu(shifted, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True})
    return int(np.count_nonzero(lu.U.diagonal() < 0.0))


def null_space(matrix: sp.spmatrix, tolerance: float = ZERO_TOLERANCE, vectors: bool = True,
               max_vectors: int = 400) -> tuple[int, np.ndarray | None]:
    """Dimension and (if asked and at most ``max_vectors``) an orthonormal basis (n, d) of the
    null space of a symmetric positive semi-definite ``matrix``: eigenvalues below ``tolerance``
    times its largest diagonal entry."""
    n = matrix.shape[0]
    scale = float(np.abs(matrix.diagonal()).max()) if n else 0.0
    if scale == 0.0:
        return n, (np.eye(n) if vectors and n <= max_vectors else None)
    threshold = tolerance * scale
    count = count_below(matrix, threshold)
    if not vectors or count == 0 or count > max_vectors:
        return count, (np.zeros((n, 0)) if vectors and count == 0 else None)
    if n <= DENSE_SIZE or count >= n - 1:
        values, basis = np.linalg.eigh(matrix.toarray())
        return count, basis[:, :count]
    values, basis = spla.eigsh(matrix.tocsc(), k=count, sigma=-threshold, which="LM")
    return count, basis[:, np.argsort(values)]


def regularised_solve(matrix: sp.spmatrix, rhs: np.ndarray) -> np.ndarray:
    """v with (matrix + delta I) v = rhs, delta 1e-10 of the largest diagonal entry: the solution
    of matrix v = rhs without components along its null modes (when rhs leaves them alone)."""
    n = matrix.shape[0]
    delta = 1e-10 * float(np.abs(matrix.diagonal()).max() or 1.0)
    if n <= SOLVE_DENSE_SIZE:
        return np.linalg.solve(matrix.toarray() + delta * np.eye(n), rhs)
    shifted = (matrix + delta * sp.identity(n, format="csc")).tocsc()
    rhs = np.asarray(rhs, dtype=float)
    try:  # diagonal pivots on the symmetric ordering: 15x faster than partial pivoting at 16 800 dof
        return spla.splu(shifted, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                         options={"SymmetricMode": True}).solve(rhs)
    except RuntimeError:  # an exactly singular pivot: partial pivoting
        return spla.splu(shifted, permc_spec="MMD_AT_PLUS_A").solve(rhs)


def response(net: Network, load_increment: np.ndarray, sliding: np.ndarray | None = None) -> np.ndarray:
    """The quasi-static velocities v for a load rate df_ext/dt (ratcheting Eqs. A3-A6; quasi-rigidity
    Eq. 39: df_ext/dt = k v), the contacts of ``sliding`` sliding (default: the dynamics' statuses);
    the components ``net.fixed`` stay zero."""
    load_increment = np.asarray(load_increment, dtype=float)
    if load_increment.shape != (net.dof,):
        raise ParameterError("load increment", f"shape {load_increment.shape}",
                             f"one value per velocity component: ({net.dof},)")
    k = stiffness_matrix(net, sliding)
    if net.fixed is None:
        return regularised_solve(k, load_increment)
    free = ~net.fixed
    v = np.zeros(net.dof)
    v[free] = regularised_solve(k.tocsr()[free][:, free], load_increment[free])
    return v


def rattler_disks(net: Network) -> np.ndarray:
    """Disks with no interaction at all: each brings three null modes of k (quasi-rigidity Sec. III E)."""
    touched = np.zeros(net.disks, dtype=bool)
    touched[net.first] = True
    touched[net.second[net.second >= 0]] = True
    return np.flatnonzero(~touched)


def _rigid_motions(net: Network) -> np.ndarray:
    """(n_dof, 3) translations along x and y and the rotation about the centroid of everything,
    each disk turning with it (walls translate along their normal; a rotation moves no wall)."""
    n = net.disks
    out = np.zeros((net.dof, 3))
    for axis in range(2):
        out[axis: 3 * n: 3, axis] = 1.0
        mobile = net.wall_dof >= 0
        out[net.wall_dof[mobile], axis] = net.wall_normals[mobile, axis]
    if not len(net.wall_normals):
        centred = net.positions - net.positions.mean(axis=0)
        out[0: 3 * n: 3, 2] = -centred[:, 1]
        out[1: 3 * n: 3, 2] = centred[:, 0]
        out[2: 3 * n: 3, 2] = net.radii
    return out


def _split(basis: np.ndarray, vectors: np.ndarray, tolerance: float = 1e-6,
           angle_tolerance: float = 1e-3) -> tuple[int, np.ndarray]:
    """Dimension of the intersection of span(basis) (orthonormal columns) with span(vectors), and an
    orthonormal basis of the rest of span(basis) (its part orthogonal to that intersection).
    A direction is shared when the cosine of its principal angle exceeds ``1 - angle_tolerance``
    (null vectors from ARPACK on a large packing lie within 1e-4 of the exact ones)."""
    if basis.shape[1] == 0 or vectors.shape[1] == 0:
        return 0, basis
    q, r = np.linalg.qr(vectors)
    q = q[:, np.abs(np.diag(r)) > tolerance * max(1.0, np.abs(r).max())]
    if q.shape[1] == 0:
        return 0, basis
    _, sigma, vt = np.linalg.svd(q.T @ basis)
    shared = int(np.count_nonzero(sigma > 1.0 - angle_tolerance))
    return shared, basis @ vt[shared:].T


@dataclass(frozen=True)
class Mechanisms:
    """Null modes of k (quasi-rigidity Sec. III E) and what they are.

    ``count`` zero modes, of which ``rigid_body`` are motions of the whole, ``rattlers`` those of
    disks without interactions (three each), ``unexcited`` those of the others the load
    increment does not excite (f_ext · v* = 0); ``collapse`` is true when the load has a component along the rest:
    then Eq. 39 has no solution and the packing collapses (``collapse_mode``, the excited motion).
    ``unstable`` counts directions with Q = vᵀkv < 0 (motion through an instability). ``modes``
    (n_dof, count - 3 x rattler disks) is a basis of the modes outside the rattlers (None if too
    many; then the classification is None), ``internal`` a basis of those that are not motions of
    the whole (None with ``modes``)."""

    count: int
    rigid_body: int | None
    rattlers: int
    unexcited: int | None
    collapse: bool | None
    unstable: int
    modes: np.ndarray | None
    collapse_mode: np.ndarray | None
    internal: np.ndarray | None

    @property
    def drawn_mode(self) -> np.ndarray | None:
        """The mode the lab draws as arrows: the one that collapses the packing, or else the first
        internal mechanism; None without one (a translation of a periodic cell's packing, drawn as
        one arrow on every disk, was shown as its mechanism)."""
        if self.collapse_mode is not None:
            return self.collapse_mode
        if self.internal is not None and self.internal.shape[1]:
            return self.internal[:, 0]
        return None

    def as_dict(self) -> dict:
        return {"null_modes": self.count, "rigid_body_modes": self.rigid_body, "rattler_modes": self.rattlers,
                "unexcited_mechanisms": self.unexcited, "collapse": self.collapse, "unstable_directions": self.unstable}


def mechanisms(net: Network, load_increment: np.ndarray | None = None, sliding: np.ndarray | None = None,
               tolerance: float = ZERO_TOLERANCE, max_vectors: int = 400) -> Mechanisms:
    """Null modes of the symmetric part of k(𝕊) and their classification (quasi-rigidity Sec. III E)
    for the load increment (default: the current load, ``net.external``). The three modes of each
    disk without interactions are counted without computing them."""
    load = net.external if load_increment is None else np.asarray(load_increment, dtype=float)
    k = stiffness_matrix(net, sliding)
    sym = ((k + k.T) * 0.5).tocsr()
    loose = rattler_disks(net)
    keep = np.ones(net.dof, dtype=bool)
    for offset in range(3):
        keep[3 * loose + offset] = False
    index = np.flatnonzero(keep)
    reduced = sym[index][:, index].tocsc()
    scale = float(np.abs(reduced.diagonal()).max()) if len(index) else 0.0
    unstable = count_below(reduced, -tolerance * scale) if scale > 0 else 0
    zero, basis = null_space(reduced, tolerance, vectors=True, max_vectors=max_vectors)
    zero -= unstable
    modes = collapse_mode = rigid = others = unexcited = collapse = None  # unknown without the modes
    if basis is not None:
        modes = np.zeros((net.dof, basis.shape[1]))
        modes[index] = basis
        if unstable:
            modes = modes[:, unstable:]
        rigid_vectors = _rigid_motions(net)
        rigid_vectors[~keep] = 0.0
        rigid, others = _split(modes, rigid_vectors)
        along = modes.T @ load
        size = np.linalg.norm(load)
        collapse = bool(size > 0 and np.linalg.norm(along) > 1e-8 * size)
        unexcited = others.shape[1] - int(size > 0 and np.linalg.norm(others.T @ load) > 1e-8 * size)
        if collapse:
            collapse_mode = modes @ (along / np.linalg.norm(along))
    return Mechanisms(zero + 3 * len(loose), rigid, 3 * len(loose), unexcited, collapse, unstable, modes,
                      collapse_mode, others)


# ---------------------------------------------------------------------------------------- the analysis

MODE_VECTORS = 400
"""Null modes of k the stiffness analysis computes and classifies; more are only counted."""
LOAD_TEXTS = {"walls": "the walls' loads raised in proportion",
              "random": "random forces on the disks, adding up to zero (seeded)",
              "none": "none: no disk touches two others (or a wall and another) for a random force to push"}


def unclassified(max_vectors: int) -> str:
    """Why null modes are not classified when there are more than ``max_vectors``."""
    return (f"more than {max_vectors} null modes besides the rattlers': their vectors are not computed, "
            f"so they are not classified")


def _load_on(net: Network, dof: np.ndarray) -> np.ndarray:
    """The external load on the velocity components ``dof`` (-1: none), zero elsewhere."""
    out = np.zeros(net.dof)
    out[dof[dof >= 0]] = net.external[dof[dof >= 0]]
    return out


def load_increment(net: Network, load: str = "auto", seed: int = 0) -> tuple[np.ndarray, str]:
    """The load increment df_ext (one value per velocity component) and the name of its kind.

    ``walls`` raises every load on a force-controlled wall in proportion; ``cell`` raises the target
    stress of each axis of a periodic cell under stress control in proportion (its lengths are then
    bodies of k, Gilabert App. A); ``random`` pushes each disk with a random force (seeded);
    ``auto`` takes ``walls`` when walls are loaded and ``random`` otherwise. The random forces act
    on the disks with at least two interactions and add up to zero, so they excite neither
    rattlers, nor a disk hanging by one contact (a mechanism of its own), nor a translation of the
    whole; with no such disk (a pair of disks alone) the increment is zero, named ``none``. The
    principle of minimum sliding holds for any increment."""
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
    if len(bound) == 0:
        return out, "none"
    forces = rng.normal(size=(len(bound), 2))
    forces -= forces.mean(axis=0)
    out[3 * bound], out[3 * bound + 1] = forces[:, 0], forces[:, 1]
    return out / np.linalg.norm(out), "random"


def network_with_contacts(state) -> Network:
    """The stiffness network of ``state``, which must have contacts."""
    net = network(state)
    if net.contacts == 0:
        raise GranLabError("the state has no contacts: there is no stiffness matrix, status or rigidity to analyse")
    return net


def run(state, clock: Clock, load: str, seed: int) -> AnalysisReport:
    """k = cKScᵀ with the dynamics' statuses, its null modes and their classification for a load
    increment (quasi-rigidity Sec. III E); the result is the :class:`Mechanisms`."""
    require_forces(state, "the stiffness analysis")
    net = network_with_contacts(state)
    k = stiffness_matrix(net)
    clock.lap("stiffness_matrix")
    increment, kind = load_increment(net, load, seed)
    mech = mechanisms(net, increment, max_vectors=MODE_VECTORS)
    clock.lap("mechanisms")
    asymmetry = abs(k - k.T).max() / max(abs(k).max(), 1e-300)
    values = {"disks": net.disks, "dof": net.dof, "contacts": net.contacts,
              "sliding_contacts": int(np.count_nonzero(net.sliding)),
              "distant_interactions": int(np.count_nonzero(net.distant)), "nonzeros": int(k.nnz),
              "asymmetry": float(asymmetry), "load": kind, **mech.as_dict()}
    reasons = {} if mech.modes is not None else dict.fromkeys(("rigid_body_modes", "unexcited_mechanisms", "collapse"),
                                                              unclassified(MODE_VECTORS))
    mode = mech.drawn_mode
    moves_disks = mode is not None and bool(np.any(mode[:3 * net.disks].reshape(-1, 3)[:, :2] != 0.0))
    return AnalysisReport("stiffness", values, mech, reasons=reasons, texts={"load": LOAD_TEXTS.get(kind, kind)},
                          figures=("mechanism",) if moves_disks else ())
