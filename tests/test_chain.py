"""PendulumChain: the shared checks, the model and the adjoint.

The chain is the model of the keyframe-control example
(examples/keyframe_chain.py): beads on stiff springs under gravity, pinned
at atom 0 by FixAtoms.  Tolerances on finite differences were measured
(values in the comments) and set with a margin of at least ten.
"""

import numpy as np
import pytest
from ase.constraints import FixAtoms

from ase_reversible import ReversibleVerlet
from ase_reversible.calculators import PendulumChain, make_chain
from ase_reversible import INFO_KEY

from calculator_conformance import CalculatorConformance

STIFFNESS, GRAVITY = 1000.0, 1.0  # eV/Å², eV/(Å amu): as in the example
DT = 0.0125  # ASE time units; at most 0.8 rad per step, as in the example
SCHEMES = ['velocity', 'position']


def bent_chain(seed, n_links=7):
    """A chain off its rest lengths, with unequal masses (1-3 amu)."""
    rng = np.random.default_rng(seed)
    atoms = make_chain(n_links, angle=50.0,
                       mass=rng.uniform(1.0, 3.0, n_links + 1))
    atoms.positions += rng.normal(0.0, 0.15, atoms.positions.shape)
    atoms.calc = PendulumChain(stiffness=STIFFNESS, gravity=GRAVITY)
    return atoms, rng


def swinging_chain(seed, n_links=6):
    """A straight chain at 60 degrees with random momenta on free atoms."""
    rng = np.random.default_rng(seed)
    atoms = make_chain(n_links, angle=60.0)
    atoms.calc = PendulumChain(stiffness=STIFFNESS, gravity=GRAVITY)
    p_nc = np.zeros((n_links + 1, 3))
    p_nc[1:] = rng.normal(0.0, 1.0, (n_links, 3))
    atoms.set_momenta(p_nc, apply_constraint=False)
    return atoms, rng


def _with_momenta(atoms, seed=8):
    p_nc = np.zeros((len(atoms), 3))
    p_nc[1:] = np.random.default_rng(seed).normal(0.0, 1.0,
                                                  (len(atoms) - 1, 3))
    atoms.set_momenta(p_nc, apply_constraint=False)
    return atoms


class TestPendulumChain(CalculatorConformance):
    # Off their rest lengths: a straight chain would feel gravity alone,
    # which no check of the springs can see.
    systems = {'7 links': lambda: _with_momenta(bent_chain(5)[0]),
               '3 links': lambda: _with_momenta(bent_chain(9, 3)[0])}
    # Stretched springs swing fast: a quarter of the example's step keeps
    # the energy within ReversibleVerlet's check.
    timestep = DT / 4
    reversal_steps = 2000  # 6 time units: a swing of the chain
    external_field = True
    masses_matter = True
    # Measured 0.6-1.3e-10 of max|F| (gradient) and 2-9e-10 of max|Hv| on
    # five chains, falling 100-fold per 10-fold smaller h: truncation.
    gradient_tolerance = 1e-8
    hessian_tolerance = 1e-8
    parameter_change = {'gravity': 2 * GRAVITY}
    bad_parameters = [({'stiffness': 0.0}, ValueError, 'stiffness'),
                      ({'stiffness': float('nan')}, ValueError, 'stiffness'),
                      ({'rest_length': -1.0}, ValueError, 'rest_length'),
                      ({'gravity': -9.8}, ValueError, 'gravity'),
                      ({'gravity': 'down'}, TypeError, 'gravity')]

    def make_calc(self, **parameters):
        parameters = {'stiffness': STIFFNESS, 'gravity': GRAVITY,
                      **parameters}
        return PendulumChain(**parameters)


# -- the model ------------------------------------------------------------

def test_unstretched_chain_feels_gravity_only():
    atoms = make_chain(5, angle=0.0, mass=[1, 2, 3, 4, 5, 6])
    atoms.calc = PendulumChain(stiffness=STIFFNESS, gravity=GRAVITY)
    expected_nc = np.zeros((6, 3))
    expected_nc[:, 2] = -GRAVITY * atoms.get_masses()
    # Links of exactly 1 Å carry no tension, whatever the stiffness.
    assert np.array_equal(atoms.get_forces(apply_constraint=False),
                          expected_nc)
    heights = atoms.positions[:, 2]
    assert np.isclose(atoms.get_potential_energy(),
                      GRAVITY * np.dot(atoms.get_masses(), heights))


def test_coincident_atoms_are_refused():
    atoms = make_chain(2)
    atoms.positions[2] = atoms.positions[1]
    atoms.calc = PendulumChain()
    with pytest.raises(ValueError, match='coincide'):
        atoms.get_forces()


def test_make_chain():
    atoms = make_chain(4, link_length=1.5, mass=2.0, angle=90.0)
    assert len(atoms) == 5
    assert np.allclose(atoms.positions[:, 0], 1.5 * np.arange(5))
    assert np.array_equal(atoms.positions[:, 1:], np.zeros((5, 2)))
    assert np.array_equal(atoms.get_masses(), np.full(5, 2.0))
    assert not atoms.pbc.any()
    assert [type(c) for c in atoms.constraints] == [FixAtoms]
    assert list(atoms.constraints[0].index) == [0]
    hanging = make_chain(3, angle=0.0).positions
    assert np.allclose(hanging[:, 2], -np.arange(4))
    assert np.allclose(hanging[:, :2], 0.0)


# -- with ReversibleVerlet ------------------------------------------------

@pytest.mark.parametrize('scheme', SCHEMES)
def test_backpropagate_matches_finite_difference_of_the_run(scheme):
    """dL/dp0 and dL/dx0 of L = a.x(T) + b.p(T) against the whole run."""
    atoms, rng = swinging_chain(7)
    steps = 160  # T = 2 time units, as in the example
    n = len(atoms)
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    a_nc, b_nc = rng.normal(size=(2, n, 3))
    d_nc = np.zeros((n, 3))
    d_nc[1:] = rng.normal(size=(n - 1, 3))  # free atoms only
    d_nc /= np.linalg.norm(d_nc)

    def start(x_nc, p_nc):
        atoms.info.pop(INFO_KEY, None)  # a fresh run, not a restart
        atoms.set_positions(x_nc, apply_constraint=False)
        atoms.set_momenta(p_nc, apply_constraint=False)
        # Fine quanta (range 32 Å and 32 amu Å / time unit, ample here)
        # keep the rounding noise of the run ~1e-13 in the loss.
        return ReversibleVerlet(atoms, DT, scheme=scheme,
                                position_quantum=2.0**-48,
                                momentum_quantum=2.0**-48)

    def loss(x_nc, p_nc):
        start(x_nc, p_nc).run(steps)
        return np.vdot(a_nc, atoms.positions) + np.vdot(b_nc,
                                                        atoms.get_momenta())

    dyn = start(x0_nc, p0_nc)
    dyn.run(steps)
    grad = dyn.backpropagate(steps, a_nc, b_nc)
    assert grad.hessian_vector_products > 0

    # eps balances truncation (~eps²) against the run's rounding noise
    # (~1/eps).  Over 12 random chains and both schemes, |fd - grad.d| /
    # |grad| was at most 1.5e-8 for momenta at eps = 3e-5 (4e-6 at 1e-3)
    # and 2.4e-8 for positions at eps = 1e-5 (2.5e-4 at 1e-3: a shift of
    # the positions excites the stiff springs, so truncation is larger).
    for g_nc, eps, shift in (
            (grad.momenta, 3e-5, lambda e: (x0_nc, p0_nc + e * d_nc)),
            (grad.positions, 1e-5, lambda e: (x0_nc + e * d_nc, p0_nc))):
        fd = (loss(*shift(eps)) - loss(*shift(-eps))) / (2 * eps)
        error = abs(fd - np.vdot(g_nc, d_nc)) / np.linalg.norm(g_nc[1:])
        assert error < 3e-7, error
