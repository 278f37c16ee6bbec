"""Whether a state read from a file describes a packing at all: a file that reads without error
can still be wrong (a column read as another, diameters under a radius's name, a ``dump local``
of normal forces alone), and every analysis of it would be numbers without meaning. Each finding
is one line naming what is off and its likely cause; ``granlab analyze`` prints them as warnings."""

from __future__ import annotations

import numpy as np

from ..observables import interacting, solid_fraction
from .states import contact_force_vectors

UNBALANCED_FORCE = 0.1
"""A disk's net contact force, as a fraction of the mean contact force, above which it is out of balance."""
UNBALANCED_SHARE = 0.1
"""The share of the disks out of balance above which the forces are said not to balance."""


def implausible(state) -> list[str]:
    """What makes ``state`` (:class:`granlab.engine.analysis.states.PackingState`) unphysical, one line each."""
    findings = []
    n = state.disks
    phi = solid_fraction(state.radii, state.box_lengths)
    if phi > 1.0:
        findings.append(f"the solid fraction is {phi:.4g}, above 1: the disks are larger than their box; is another "
                        f"column read as the radius, or are the sizes diameters under a radius's name?")
    c = state.contacts
    pair = (c.j < n) & interacting(c.status)
    depth = -c.surface_gap[pair] / np.minimum(state.radii[c.i[pair]], state.radii[c.j[pair]])
    deep = int(np.count_nonzero(depth > 1.0))
    if deep:
        findings.append(f"{deep} pairs of disks overlap by more than the smaller radius (the deepest by "
                        f"{float(depth.max()):.4g} of it): are the positions or radii read from the right columns?")
    if n > 1 and not np.any(pair):
        findings.append("no two disks touch, so the coordination number means nothing: are the sizes radii under a "
                        "diameter's name (halved on reading)? (the contact tolerance is --gap)")
    if state.forces_known and not state.law_given and np.any(pair):
        findings += _unbalanced(state, pair)
    return findings


def _unbalanced(state, pair: np.ndarray) -> list[str]:
    """Another code's forces: do the disks they touch feel a net force near zero, as at rest?"""
    c, n = state.contacts, state.disks
    i, j = c.i[pair], c.j[pair]
    _, force = contact_force_vectors(state.positions, c, state.box_lengths, pair)
    net = np.zeros((n, 2))
    np.add.at(net, i, force)
    np.add.at(net, j, -force)
    mean = float(np.mean(np.hypot(force[:, 0], force[:, 1])))
    touched = (np.bincount(i, minlength=n) + np.bincount(j, minlength=n)) > 0
    off = np.hypot(net[:, 0], net[:, 1]) / mean if mean > 0 else np.zeros(n)
    out = touched & (off > UNBALANCED_FORCE)
    if np.count_nonzero(out) <= UNBALANCED_SHARE * np.count_nonzero(touched):
        return []
    # F_t from a normal force alone is rounding
    tangential = np.max(np.abs(c.tangential_force[pair])) > 1e-9 * np.max(np.abs(c.normal_force[pair]))
    return [f"the contact forces do not balance: {np.count_nonzero(out)} of {np.count_nonzero(touched)} disks feel a "
            f"net force above {UNBALANCED_FORCE:g} of the mean contact force (up to {float(off.max()):.3g} of it): "
            + ("the dump local holds normal forces only (dump the tangential ones too, e.g. ftx fty)" if not tangential
               else "the packing was not at rest, or a force column is read as another")]
