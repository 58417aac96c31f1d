"""SoftenedGravity and make_ring: the shared checks, the model, the
collapse and the adjoint.

The calculator drives the ring-collapse scene (examples/ring_collapse.py).
Tolerances on finite differences were measured (values in the comments)
and set with a margin of at least ten.
"""

import numpy as np
import pytest

from ase_reversible import ReversibleVerlet
from ase_reversible.calculators import SoftenedGravity, make_ring
from ase_reversible import INFO_KEY

from calculator_conformance import CalculatorConformance
from tiers import SLOW

G, EPS, DT = 1.0, 0.3, 0.002  # eV Å/amu², Å, ASE time: as in the scene


def lumpy_ring(seed, n=12):
    """A jittered ring with unequal masses (1-4 amu) and some spin."""
    rng = np.random.default_rng(seed)
    atoms = make_ring(n, radius=3.0, spin=0.5, jitter=0.4, seed=seed)
    atoms.set_masses(rng.uniform(1.0, 4.0, n))
    atoms.positions[:, 2] = rng.normal(0.0, 0.5, n)  # off the plane too
    atoms.calc = SoftenedGravity(G=G, softening=EPS)
    return atoms, rng


class TestSoftenedGravity(CalculatorConformance):
    systems = {'lumpy ring': lambda: lumpy_ring(0)[0],
               'small lumpy ring': lambda: lumpy_ring(5, n=5)[0]}
    timestep = DT
    reversal_steps = 1500
    masses_matter = True
    # Measured 2.4-3.5e-10 of max|F| (gradient) and 4-9e-10 of max|Hv| on
    # five such rings (seeds 0-4).
    gradient_tolerance = 1e-8
    hessian_tolerance = 1e-8
    parameter_change = {'G': 2 * G}
    bad_parameters = [({'G': 0.0}, ValueError, 'must be'),
                      ({'G': -1.0}, ValueError, 'must be'),
                      ({'softening': 0.0}, ValueError, 'must be'),
                      ({'softening': float('inf')}, ValueError, 'must be'),
                      ({'G': 'big'}, TypeError, 'must be')]

    def make_calc(self, **parameters):
        return SoftenedGravity(**{'G': G, 'softening': EPS, **parameters})


def test_two_bodies_match_the_formula():
    atoms = make_ring(2, radius=1.5)
    atoms.set_masses([2.0, 3.0])
    atoms.calc = SoftenedGravity(G=0.7, softening=0.4)
    s = 3.0**2 + 0.4**2
    assert np.isclose(atoms.get_potential_energy(),
                      -0.7 * 6.0 / np.sqrt(s), rtol=1e-14)
    f_nc = atoms.get_forces()
    # Body 0 at +x is pulled towards body 1 at -x.
    pull = 0.7 * 6.0 * 3.0 / s**1.5
    assert np.allclose(f_nc[0], [-pull, 0, 0], rtol=1e-14, atol=1e-15)
    assert np.array_equal(f_nc[1], -f_nc[0])


def test_forces_scale_with_both_masses():
    atoms, _ = lumpy_ring(3)
    f_nc = atoms.get_forces()
    atoms.set_masses(2 * atoms.get_masses())
    assert np.allclose(atoms.get_forces(), 4 * f_nc, rtol=1e-14)


def test_make_ring():
    atoms = make_ring(8, radius=2.0, mass=3.0, spin=1.5)
    r_n = np.linalg.norm(atoms.positions, axis=1)
    assert np.allclose(r_n, 2.0)
    assert np.array_equal(atoms.positions[:, 2], np.zeros(8))
    v_nc = atoms.get_velocities()
    assert np.allclose(np.linalg.norm(v_nc, axis=1), 1.5)
    assert np.allclose(np.einsum('nc,nc->n', v_nc, atoms.positions), 0.0,
                       atol=1e-12)
    assert not atoms.pbc.any()
    with pytest.raises(ValueError, match='at least 2'):
        make_ring(1)
    with pytest.raises(ValueError, match='radius'):
        make_ring(5, radius=-1.0)


# -- with ReversibleVerlet ------------------------------------------------

@pytest.mark.parametrize('scheme, order', [
    ('velocity', 2), ('position', 2),
    pytest.param('velocity', 4, marks=SLOW)])
def test_collapse_reverses_exactly(scheme, order):
    atoms = make_ring(40, radius=10.0, jitter=0.05)
    atoms.calc = SoftenedGravity(G=G, softening=EPS)
    dyn = ReversibleVerlet(atoms, DT, scheme=scheme, order=order,
                           energy_check=0)
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    steps = 1500  # 3 time units: well into the fall (40 bodies fall slower)
    dyn.run(steps)
    assert np.sqrt((atoms.positions**2).sum(axis=1).mean()) < 9.0  # fell in
    dyn.reverse()
    dyn.run(steps)
    assert np.array_equal(atoms.positions, x0_nc)
    assert np.array_equal(atoms.get_momenta(), p0_nc)
    # The motion stays in the plane exactly: no force has a z component.
    assert np.array_equal(atoms.positions[:, 2], np.zeros(len(atoms)))


def test_backpropagate_matches_finite_difference_of_the_run():
    atoms, rng = lumpy_ring(5, n=8)
    steps = 200
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    a_nc = rng.normal(size=x0_nc.shape)
    d_nc = rng.normal(size=x0_nc.shape)
    d_nc /= np.linalg.norm(d_nc)

    def start(x_nc):
        atoms.info.pop(INFO_KEY, None)
        atoms.set_positions(x_nc)
        atoms.set_momenta(p0_nc)
        return ReversibleVerlet(atoms, DT, energy_check=0,
                                position_quantum=2.0**-48,
                                momentum_quantum=2.0**-48)

    def loss(x_nc):
        start(x_nc).run(steps)
        return float(np.vdot(a_nc, atoms.positions))

    dyn = start(x0_nc)
    dyn.run(steps)
    grads = dyn.backpropagate(steps, a_nc)
    assert grads.hessian_vector_products == steps  # analytic, no dL/dp
    h = 1e-5
    fd = (loss(x0_nc + h * d_nc) - loss(x0_nc - h * d_nc)) / (2 * h)
    # Measured relative error 8e-9 here, 6e-9 to 8e-8 over seeds 5-9
    # (h = 1e-6 gives up to 5e-7: rounding of the loss dominates).
    assert abs(np.vdot(grads.positions, d_nc) - fd) < 1e-6 * abs(fd)
