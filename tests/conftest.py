"""Systems and calculators shared by the tests.

Every calculator here is a real one (ASE's or asap3's); builders return
fresh Atoms with thermal momenta drawn from a fixed seed.
"""

import warnings

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase_reversible import AnchorMovedWarning
from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,  # noqa: F401
                                         argon_bulk, argon_cluster,
                                         copper_bulk, copper_cluster,
                                         thermalize)

try:
    import asap3
except ImportError:  # an optional extra: tests that need it skip one by one
    asap3 = None

DT = 5 * units.fs


def ase_lj():
    return LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)


def needs_asap3():
    """Skip the calling test, with the reason, where asap3 is missing."""
    if asap3 is None:
        pytest.skip('asap3 is not installed (it is in the test extra: '
                    "pip install '.[test]')")
    return asap3


def asap_lj():
    return needs_asap3().LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                                      rCut=AR_RC, modified=True)


def asap_emt():
    return needs_asap3().EMT()


CALCULATORS = {'ase-lj': ase_lj, 'asap-lj': asap_lj,
               'ase-emt': EMT, 'asap-emt': asap_emt}


def snapshot(atoms):
    return atoms.get_positions(), atoms.get_momenta()


def assert_same_state(atoms, reference):
    positions, momenta = reference
    assert np.array_equal(atoms.get_positions(), positions)
    assert np.array_equal(atoms.get_momenta(), momenta)


def forward_and_back(dyn, steps):
    """Run `steps`, reverse, run `steps`; return the state after the constructor."""
    start = snapshot(dyn.atoms)
    dyn.run(steps)
    moved = not np.array_equal(dyn.atoms.get_positions(), start[0])
    dyn.reverse()
    dyn.run(steps)
    return start, moved


def assert_runs_back(dyn, steps):
    """Run ``steps`` out and back: the atoms moved, and returned bit for bit."""
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


# -- finite differences, for checking derivatives ---------------------------

def central_difference(function, x0, direction, h):
    """``(f(x0 + h d) - f(x0 - h d)) / 2h``."""
    return (function(x0 + h * direction) - function(x0 - h * direction)) \
        / (2 * h)


def at_positions(atoms, quantity):
    """``quantity()`` as a function of the positions ``[n_atoms, 3]``."""
    def evaluate(x_nc):
        atoms.positions = x_nc
        return quantity()
    return evaluate


def energy_gradient(atoms, h):
    """dE/dx ``[n_atoms, 3]`` (eV/Å), one coordinate at a time."""
    x0_nc = atoms.get_positions()
    energy = at_positions(atoms, atoms.get_potential_energy)
    grad_nc = np.zeros_like(x0_nc)
    for i in range(len(atoms)):
        for c in range(3):
            unit_nc = np.zeros_like(x0_nc)
            unit_nc[i, c] = 1.0
            grad_nc[i, c] = central_difference(energy, x0_nc, unit_nc, h)
    atoms.positions = x0_nc
    return grad_nc


def hessian_times(atoms, v_nc, h):
    """``H v`` from the forces along ``v_nc`` (constraints not applied)."""
    x0_nc = atoms.get_positions()
    forces = at_positions(
        atoms, lambda: atoms.get_forces(apply_constraint=False))
    hv_nc = -central_difference(forces, x0_nc, v_nc, h)
    atoms.positions = x0_nc
    return hv_nc
