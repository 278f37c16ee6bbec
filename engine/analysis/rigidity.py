"""The rigidity analysis: Gilabert's counts N_f + H = M + K of the rigidity matrix G (App. A),
and whether the stiffness matrix k is positive definite apart from rigid motions and rattlers."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .report import AnalysisReport, Clock
from .stiffness import (DENSE_SIZE, NORMAL, ZERO_TOLERANCE, Network, compatibility, components, mechanisms,
                        network_with_contacts, null_space, unclassified)

LABELS = {
    "degrees_of_freedom": "Degrees of freedom N_f: 3 per disk, 1 per loaded wall or stress-controlled cell length "
                          "(Gilabert App. A)",
    "constraints": "Constraints M: relative motions that carry forces",
    "floppy_modes": "Floppy modes K = dim null G",
    "hyperstaticity": "Degree of hyperstaticity H = dim null Gᵀ",
    "rank": "Rank of the rigidity matrix G",
    "balanced": "N_f + H = M + K holds (Gilabert Eq. 19)",
    "stiffness_null_modes": "Null modes of k",
    "stiffness_unstable_directions": "Unstable directions of k, Q < 0",
    "stiffness_positive_definite": "k positive definite apart from rigid motions and rattlers",
    "forces_known": "Contact forces known",
}
"""The label of each value of the rigidity analysis (:func:`run`)."""
MODE_VECTORS = 40
"""Null modes of k the rigidity analysis computes, only to tell rigid motions apart."""


@dataclass(frozen=True)
class Rigidity:
    """Counts of Gilabert App. A for the rigidity matrix G (M × N_f): ``degrees_of_freedom`` N_f,
    ``constraints`` M (relative motions that carry forces), ``floppy_modes`` K = dim null G,
    ``hyperstaticity`` H = dim null Gᵀ (self-stress states), ``rank``; N_f + H = M + K holds when the
    two null spaces were measured consistently (``balanced``; None when H was not measured but
    taken from rank–nullity, ``hyperstaticity_measured`` False)."""

    degrees_of_freedom: int
    constraints: int
    floppy_modes: int
    hyperstaticity: int
    rank: int
    hyperstaticity_measured: bool = True

    @property
    def balanced(self) -> bool | None:
        if not self.hyperstaticity_measured:
            return None
        return self.degrees_of_freedom + self.hyperstaticity == self.constraints + self.floppy_modes

    def as_dict(self) -> dict:
        counts = asdict(self)
        del counts["hyperstaticity_measured"]  # said by ``balanced`` (None) and the report's reason
        return dict(counts, balanced=self.balanced)


def rigidity_matrix(net: Network) -> sp.csr_matrix:
    """G = cᵀ restricted to the relative motions that carry forces (Gilabert Eq. A3): normal
    components of every interaction; tangential ones of touching contacts with friction; rolling
    ones with a rolling spring. Without friction nor rolling resistance the rotations are left out
    (N_f = 2N, Gilabert Eq. 22)."""
    comps = components(net)
    c = compatibility(net, comps).T.tocsr()
    keep = np.ones((net.contacts, len(comps)), dtype=bool)
    keep[:, 1:] = ~net.distant[:, None]
    g = c[np.flatnonzero(keep.ravel())]
    if comps == (NORMAL,):
        translations = np.concatenate([np.flatnonzero((np.arange(3 * net.disks) % 3) != 2),
                                       np.arange(3 * net.disks, net.dof)])
        g = g[:, translations]
    return g.tocsr()


def self_stress_states(g: sp.spmatrix, tolerance: float = ZERO_TOLERANCE, dense_size: int = DENSE_SIZE) -> int:
    """dim null Gᵀ: the eigenvalues of GGᵀ below ``tolerance`` times its largest diagonal entry,
    counted without forming GGᵀ above ``dense_size`` constraints. Its factorisation filled
    SuperLU's memory after 8 s on a packing of 5600 disks (GGᵀ 14 732 × 14 732); the augmented
    matrix [[−I, Gᵀ], [G, −t I]], as sparse as G, factorises in 0.4 s. By Sylvester's law of
    inertia its negative pivots are those of −I (N_f) and of its Schur complement GGᵀ − t I."""
    m, nf = g.shape
    scale = float(np.asarray(g.multiply(g).sum(axis=1)).max()) if m else 0.0
    if m <= dense_size or scale == 0.0:
        return null_space((g @ g.T).tocsc(), tolerance, vectors=False)[0]
    augmented = sp.bmat([[-sp.identity(nf), g.T], [g, -tolerance * scale * sp.identity(m)]], format="csc")
    lu = spla.splu(augmented, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return int(np.count_nonzero(lu.U.diagonal() < 0.0)) - nf


def rigidity(net: Network, tolerance: float = ZERO_TOLERANCE) -> Rigidity:
    """K from the null space of GᵀG and H by :func:`self_stress_states`, each by its own
    factorisation. Where SuperLU runs out of memory all the same, H is taken from rank–nullity,
    M − rank G, and the balance is not checked."""
    g = rigidity_matrix(net)
    m, nf = g.shape
    floppy, _ = null_space((g.T @ g).tocsc(), tolerance, vectors=False)
    try:
        stress = self_stress_states(g, tolerance)
    except MemoryError:
        return Rigidity(nf, m, floppy, m - (nf - floppy), nf - floppy, hyperstaticity_measured=False)
    return Rigidity(nf, m, floppy, stress, nf - floppy)


def run(state, clock: Clock, load: str, seed: int) -> AnalysisReport:
    """The counts of :func:`rigidity` and the inertia of k; the result is the :class:`Rigidity`.
    Contacts found from the geometry will do: no force is needed."""
    net = network_with_contacts(state)
    counts = rigidity(net)
    clock.lap("rigidity")
    mech = mechanisms(net, np.zeros(net.dof), max_vectors=MODE_VECTORS)
    clock.lap("stiffness_inertia")
    internal = None if mech.rigid_body is None else mech.count - mech.rattlers - mech.rigid_body
    values = {**counts.as_dict(), "stiffness_null_modes": mech.count, "stiffness_unstable_directions": mech.unstable,
              "stiffness_positive_definite": None if internal is None else bool(internal == 0 and mech.unstable == 0),
              "forces_known": state.forces_known}
    reasons = {} if internal is not None else {"stiffness_positive_definite": unclassified(MODE_VECTORS)}
    if not counts.hyperstaticity_measured:
        reasons["balanced"] = ("not checked: H is M − rank G (rank–nullity), the factorisation of GGᵀ having run out "
                               "of SuperLU's memory")
    return AnalysisReport("rigidity", values, counts, reasons=reasons)
