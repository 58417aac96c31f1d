"""What the contract tests share: their two systems, the warnings a run
issues, and the comparisons of a state with its anchor."""

import warnings

import numpy as np
from ase.calculators.emt import EMT

from ase_reversible import AnchorMovedWarning
from conftest import argon_cluster, ase_lj, copper_bulk


def argon():
    """Ar13 icosahedron at 80 K with ASE's LennardJones (no pbc)."""
    atoms = argon_cluster(2, 80)
    atoms.calc = ase_lj()
    return atoms


def copper(seed=0):
    """32 rattled copper atoms at 600 K in a periodic cell, ASE's EMT."""
    atoms = copper_bulk((2, 2, 2), temperature_K=600, seed=seed)
    atoms.calc = EMT()
    return atoms


def moves(record):
    """The AnchorMovedWarnings among recorded warnings, as messages."""
    return [str(w.message) for w in record
            if issubclass(w.category, AnchorMovedWarning)]


def take_pending(dyn):
    """``dyn.run(0)``: takes (or refuses) changes without stepping.

    Returns the messages of the AnchorMovedWarnings it issued.
    """
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter('always')
        dyn.run(0)
    return moves(record)


def run_forbidding_anchor_moves(dyn, steps):
    """``dyn.run(steps)``, with any re-anchoring on the way an error."""
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(steps)


def assert_state_is_anchor(dyn):
    """The integer state is exactly the anchor reversal leads back to."""
    assert np.array_equal(dyn.state.ix_nc, dyn.anchor.ix_nc)
    assert np.array_equal(dyn.state.ip_nc, dyn.anchor.ip_nc)


def same_fixed_point_state(a, b):
    return (np.array_equal(a.ix_nc, b.ix_nc)
            and np.array_equal(a.ip_nc, b.ip_nc))
