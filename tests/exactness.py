"""Assertions that a state came back bit for bit, shared by the tests.

Exactness is asserted with :func:`numpy.array_equal`, never a tolerance:
one ulp off is a failure.
"""

import warnings

import numpy as np
import pytest

from ase_reversible import AnchorMovedWarning


def snapshot(atoms):
    return atoms.get_positions(), atoms.get_momenta()


def assert_same_state(atoms, reference):
    positions, momenta = reference
    assert np.array_equal(atoms.get_positions(), positions)
    assert np.array_equal(atoms.get_momenta(), momenta)


def forward_and_back(dyn, steps):
    """Run ``steps``, reverse, run ``steps``.

    Returns the state the run started from (positions, momenta) and
    whether the positions had moved at the turn.
    """
    start = snapshot(dyn.atoms)
    dyn.run(steps)
    moved = not np.array_equal(dyn.atoms.get_positions(), start[0])
    dyn.reverse()
    dyn.run(steps)
    return start, moved


def assert_runs_back(dyn, steps):
    """Run ``steps`` out and back: the atoms moved, and came back bit for
    bit."""
    start, moved = forward_and_back(dyn, steps)
    assert moved
    assert_same_state(dyn.atoms, start)


def assert_frame_on_grid(frame, grid):
    """Positions and momenta of a frame are whole numbers of quanta."""
    ix = frame.positions / grid.position_quantum
    ip = frame.get_momenta() / grid.momentum_quantum
    assert np.array_equal(ix, np.rint(ix))
    assert np.array_equal(ip, np.rint(ip))


def assert_frame_is_state(frame, dyn):
    """A frame decodes to the integrator's exact integer state."""
    assert np.array_equal(
        (frame.positions / dyn.grid.position_quantum).astype(np.int64),
        dyn.state.ix_nc)
    assert np.array_equal(
        (frame.get_momenta() / dyn.grid.momentum_quantum).astype(np.int64),
        dyn.state.ip_nc)


def assert_atoms_show_committed_state(dyn):
    """The atoms hold exactly what the integer state stands for."""
    assert_same_state(dyn.atoms,
                      (dyn.state.ix_nc * dyn.grid.position_quantum,
                       dyn.state.ip_nc * dyn.grid.momentum_quantum))


def run_back(dyn, steps, reference):
    """Reverse, run ``steps`` and demand ``reference`` bit for bit.

    A re-anchoring on the way would hide a state left inconsistent by an
    error, so it is made an error here.
    """
    dyn.reverse()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn.run(steps)
    assert_same_state(dyn.atoms, reference)


def run_until_refused(dyn, steps, error, match):
    """Run ``steps``, which ``error`` (its message matching ``match``) must
    stop; the failed step is rolled back: the atoms show the committed
    state.  Returns the state the run started from (positions, momenta)
    and the number of steps taken."""
    start = snapshot(dyn.atoms)
    with pytest.raises(error, match=match):
        dyn.run(steps)
    assert_atoms_show_committed_state(dyn)
    return start, dyn.nsteps


def weight_gradients_of_displacement(dyn, steps):
    """Run ``steps``, retrace them for ``L = <x_T - x_0, x_T>``'s gradient
    for every parameter of the torch calculator, check the atoms are back
    bit for bit, and assign the gradients to the model; returns the
    ``Gradients``."""
    atoms = dyn.atoms
    calc = atoms.calc
    start = snapshot(atoms)
    dyn.run(steps)
    g = dyn.backpropagate(steps, atoms.get_positions() - start[0],
                          parameters=calc.differentiable_parameters)
    assert_same_state(atoms, start)
    calc.assign_gradients(g.parameters)
    return g
