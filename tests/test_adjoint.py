"""The reversible adjoint: gradients through whole runs, checked three ways.

1. Against an independent reference: complex-step differentiation of a
   plain float Verlet run written here from scratch (holomorphic in the
   initial state, so ``Im(run(x0 + i h u)) / h`` is the directional
   derivative to machine precision, with no subtraction).
2. Against central finite differences of the whole ReversibleVerlet run,
   for runs long enough that the gradients grow by orders of magnitude
   (chaos), with argon (Lennard-Jones, exact Hessian-vector products) and
   copper (EMT, finite-difference products).
3. Structurally, over every scheme and order: the retrace returns to the
   start bit for bit, the time step keeps its sign, and a repeat of the
   forward run is exact.
"""

import numpy as np
import pytest
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as AseLennardJones
from ase.cluster import Icosahedron
from ase.constraints import FixAtoms

from ase_reversible import (FiniteDifferenceHVP, LennardJones,
                            ReversibleVerlet)
from ase_reversible.core.compositions import COMPOSITIONS, DEFAULT_FOR_ORDER

from conftest import AR_EPSILON, AR_SIGMA, DT, asap_emt, thermalize
from exactness import assert_same_state, snapshot
from tiers import tiered
from finite_differences import complex_forces

#: Fine quanta: finite differences of whole runs see rounding as noise.
FINE = {'position_quantum': 2.0**-44, 'momentum_quantum': 2.0**-46}


def argon(shells=2, temperature_K=40, seed=0, **lj):
    atoms = Icosahedron('Ar', shells, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    thermalize(atoms, temperature_K, seed)
    atoms.calc = LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA, **lj)
    return atoms


def argon_crystal(temperature_K=60, seed=0):
    atoms = bulk('Ar', 'fcc', a=5.26, cubic=True) * (3, 3, 3)
    thermalize(atoms, temperature_K, seed)
    atoms.calc = LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA)
    return atoms


def copper(temperature_K=600, seed=0):
    atoms = Icosahedron('Cu', 2)
    atoms.center(vacuum=8.0)
    thermalize(atoms, temperature_K, seed)
    atoms.calc = EMT()
    return atoms


def random_loss(atoms, seed=1):
    """A linear loss L = <a, x> + <b, p>: its gradients are a and b."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(2, len(atoms), 3))


class WholeRun:
    """L(x0, p0) = <a, x_T> + <b, p_T> over a fresh ReversibleVerlet run."""

    def __init__(self, build, steps, a_nc, b_nc, **dyn_kwargs):
        self.build, self.steps = build, steps
        self.a_nc, self.b_nc = a_nc, b_nc
        self.kwargs = {'energy_check': 0, **FINE, **dyn_kwargs}

    def __call__(self, dx_nc=0.0, dp_nc=0.0, calc_set=None):
        atoms = self.build()
        if calc_set:
            atoms.calc.set(**calc_set)
        atoms.positions = atoms.positions + dx_nc
        atoms.set_momenta(atoms.get_momenta() + dp_nc, apply_constraint=False)
        dyn = ReversibleVerlet(atoms, DT, **self.kwargs)
        dyn.run(self.steps)
        return (np.vdot(self.a_nc, atoms.positions)
                + np.vdot(self.b_nc, atoms.get_momenta()))

    def gradients(self, **backprop):
        atoms = self.build()
        dyn = ReversibleVerlet(atoms, DT, **self.kwargs)
        start = snapshot(atoms)
        dyn.run(self.steps)
        g = dyn.backpropagate(self.steps, self.a_nc, self.b_nc, **backprop)
        assert_same_state(atoms, start)
        return g


def relative_error(estimate, reference):
    return abs(estimate - reference) / abs(reference)


# -- 1. independent reference: complex step through a float Verlet run ------

def complex_step_run(x_nc, p_nc, m_n1, fractions, scheme, steps, mask_n1):
    """A float Verlet run (composition ``fractions``) on complex state."""
    def kick(c):
        nonlocal p_nc
        p_nc = p_nc + c * DT * mask_n1 * complex_forces(x_nc, AR_EPSILON,
                                                        AR_SIGMA)

    def drift(c):
        nonlocal x_nc
        x_nc = x_nc + c * DT * mask_n1 * p_nc / m_n1

    first, second = (kick, drift) if scheme == 'velocity' else (drift, kick)
    for _ in range(steps):
        for c in fractions:
            first(c / 2)
            second(c)
            first(c / 2)
    return x_nc, p_nc


@pytest.mark.parametrize('scheme', ['velocity', 'position'])
@pytest.mark.parametrize('order', [2, 4])
@pytest.mark.parametrize('fixed', [False, True])
def test_gradients_match_complex_step_reference(scheme, order, fixed):
    # No pair reaches the switch (ro = 29 Å): the package's potential is
    # then exactly the plain Lennard-Jones written above.
    def build():
        atoms = argon(2, 40, rc=30.0, ro=29.0)
        if fixed:
            atoms.set_constraint(FixAtoms([0, 5]))
        return atoms

    steps = 150
    a_nc, b_nc = random_loss(build())
    run = WholeRun(build, steps, a_nc, b_nc, scheme=scheme, order=order)
    g = run.gradients()

    atoms = build()
    ReversibleVerlet(atoms, DT, **FINE)  # snaps the start to the same grid
    x0_nc, p0_nc = atoms.positions.copy(), atoms.get_momenta()
    mask_n1 = np.ones((len(atoms), 1))
    if fixed:
        mask_n1[[0, 5]] = 0.0
    fractions = COMPOSITIONS[DEFAULT_FOR_ORDER[order]].fractions
    h = 1e-20
    rng = np.random.default_rng(7)
    for _ in range(3):
        u_nc = rng.normal(size=x0_nc.shape)
        # Fixed atoms' momenta are held at zero, not free: no direction.
        up_nc = mask_n1 * u_nc
        for dx, dp, ours, direction_nc in ((u_nc, 0, g.positions, u_nc),
                                           (0, up_nc, g.momenta, up_nc)):
            x_nc, p_nc = complex_step_run(
                x0_nc + 1j * h * dx, p0_nc + 1j * h * dp,
                atoms.get_masses()[:, None], fractions, scheme, steps,
                mask_n1)
            reference = (np.vdot(a_nc, x_nc.imag) + np.vdot(b_nc, p_nc.imag)) / h
            # The reference runs in float, ours on the fixed-point path:
            # the two paths differ by ~1e-12 Å, the gradients by ~1e-10.
            assert relative_error(np.vdot(ours, direction_nc),
                                  reference) < 1e-8


# -- 2. central finite differences of whole, chaotic runs ---------------------

@pytest.mark.parametrize('case', tiered(['argon-lj-analytic', 'copper-emt-fd',
                                         'argon-crystal-lj'], quick=[]))
def test_gradients_match_whole_run_finite_differences(case):
    build, steps, h, tolerance, min_growth = {
        # Ar55 at 60 K, 2000 steps (10 ps): the gradients grow ~190 times;
        # measured errors at this h: up to 1.7e-6 (h=1e-5: 1e-4, the
        # curvature term; h=1e-7: 6e-6, rounding noise of the runs).
        'argon-lj-analytic': (lambda: argon(3, 60), 2000, 1e-6, 1e-4, 50),
        # Cu13 at 600 K, 300 steps, with finite-difference Hessian-vector
        # products (EMT has none of its own): growth ~570, errors up to
        # 6.7e-6.
        'copper-emt-fd': (copper, 300, 1e-6, 1e-4, 100),
        # Periodic Ar108 fcc at 60 K, 250 steps: a crystal is hardly
        # chaotic (growth ~3), so a larger h is exact enough: errors up to
        # 2.2e-8 at 500 steps.
        'argon-crystal-lj': (argon_crystal, 250, 1e-5, 1e-6, 2),
    }[case]
    a_nc, b_nc = random_loss(build())
    run = WholeRun(build, steps, a_nc, b_nc)
    g = run.gradients()
    growth = max(np.abs(g.positions).max(), np.abs(g.momenta).max()) / max(
        np.abs(a_nc).max(), np.abs(b_nc).max())
    assert growth > min_growth
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(2):
        u_nc = rng.normal(size=a_nc.shape)
        fd_x = (run(dx_nc=h * u_nc) - run(dx_nc=-h * u_nc)) / (2 * h)
        fd_p = (run(dp_nc=h * u_nc) - run(dp_nc=-h * u_nc)) / (2 * h)
        errors += [relative_error(np.vdot(g.positions, u_nc), fd_x),
                   relative_error(np.vdot(g.momenta, u_nc), fd_p)]
    assert max(errors) < tolerance, errors


@pytest.mark.parametrize('name', ['epsilon', 'sigma'])
def test_parameter_gradients_match_whole_run_finite_differences(name):
    build = lambda: argon(3, 40)  # noqa: E731
    steps = 200
    a_nc, b_nc = random_loss(build())
    run = WholeRun(build, steps, a_nc, b_nc)
    g = run.gradients(parameters=(name,))
    value = build().calc.parameters[name]
    h = 1e-6 * value
    # The default cut-offs follow sigma, in the derivative as here.
    fd = (run(calc_set={name: value + h})
          - run(calc_set={name: value - h})) / (2 * h)
    assert relative_error(g.parameters[name], fd) < 1e-5


# -- 3. structure over the matrix of schemes, orders and systems ------------

SYSTEMS = {
    'free': lambda: argon(2, 60),
    'periodic': argon_crystal,
    'fixed': lambda: _fixed(argon(2, 60)),
}


def _fixed(atoms):
    atoms.set_constraint(FixAtoms([0, 3]))
    return atoms


@pytest.mark.parametrize('system', sorted(SYSTEMS))
@pytest.mark.parametrize('scheme', ['velocity', 'position'])
@pytest.mark.parametrize('order', tiered(sorted(DEFAULT_FOR_ORDER),
                                          quick=[2, 4]))
def test_retrace_is_exact_for_every_scheme_and_order(system, scheme, order):
    atoms = SYSTEMS[system]()
    dyn = ReversibleVerlet(atoms, DT, scheme=scheme, order=order)
    start = snapshot(atoms)
    steps = 20
    dyn.run(steps)
    end = snapshot(atoms)
    a_nc, b_nc = random_loss(atoms)
    g = dyn.backpropagate(steps, a_nc, b_nc)
    assert_same_state(atoms, start)
    assert dyn.dt > 0
    kicks_per_step = sum(1 for substep, _ in dyn.engine.plan
                         if substep is dyn.system.kick)
    if scheme == 'velocity':
        # Kicks meeting across a step boundary share one product.
        assert g.hessian_vector_products == steps * (kicks_per_step - 1) + 1
    else:
        assert g.hessian_vector_products == steps * kicks_per_step
    if system == 'fixed':
        # A fixed atom's momentum is not free: no gradient along it.  Its
        # position is, through the forces on the others.
        assert not np.any(g.momenta[[0, 3]])
        assert np.all(g.positions[[0, 3]] != 0)
    dyn.run(steps)
    assert_same_state(atoms, end)


def test_loss_on_several_states_by_segments():
    build = lambda: argon(2, 60)  # noqa: E731
    atoms = build()
    a1_nc, b1_nc = random_loss(atoms, seed=4)
    a2_nc, b2_nc = random_loss(atoms, seed=5)
    dyn = ReversibleVerlet(atoms, DT, **FINE)
    dyn.run(100)
    dyn.run(100)
    g2 = dyn.backpropagate(100, a2_nc, b2_nc)
    g = dyn.backpropagate(100, g2.positions + a1_nc, g2.momenta + b1_nc)

    # The same from two single-segment losses (linearity).
    whole2 = WholeRun(build, 200, a2_nc, b2_nc).gradients()
    whole1 = WholeRun(build, 100, a1_nc, b1_nc).gradients()
    np.testing.assert_allclose(g.positions, whole1.positions
                               + whole2.positions, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(g.momenta, whole1.momenta + whole2.momenta,
                               rtol=1e-9, atol=1e-9)


def test_a_reversed_run_is_differentiated_backwards():
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    dyn.reverse()
    start = snapshot(atoms)
    dyn.run(50)
    a_nc, b_nc = random_loss(atoms)
    dyn.backpropagate(50, a_nc, b_nc)
    assert_same_state(atoms, start)
    assert dyn.dt < 0


# -- Hessian-vector products ----------------------------------------------

def test_finite_difference_products_at_the_default_step():
    # Against the exact products of the package's Lennard-Jones: measured
    # 4e-10 relative at the default step (docs/adjoint.md).
    atoms = argon(4, 60)
    atoms.rattle(0.1, seed=2)
    v_nc = np.random.default_rng(0).normal(size=(len(atoms), 3))
    exact_nc = atoms.calc.hessian_vector_product(atoms, v_nc)
    x_nc = atoms.positions.copy()
    fd_nc = FiniteDifferenceHVP()(atoms, v_nc)
    assert np.array_equal(atoms.positions, x_nc)  # put back bit for bit
    assert np.abs(fd_nc - exact_nc).max() / np.abs(exact_nc).max() < 1e-8


def test_finite_difference_products_with_asap3_emt():
    # asap3 has no products of its own; the reference is a fourth-order
    # stencil at the same step (truncation ~1e-20).
    atoms = bulk('Cu', cubic=True) * (4, 4, 4)
    atoms.rattle(0.05, seed=1)
    atoms.calc = asap_emt()
    v_nc = np.random.default_rng(0).normal(size=(len(atoms), 3))
    e = FiniteDifferenceHVP().step / np.abs(v_nc).max()
    x_nc = atoms.positions.copy()
    f = {}
    for k in (-2, -1, 1, 2):
        atoms.positions = x_nc + k * e * v_nc
        f[k] = atoms.get_forces()
    atoms.positions = x_nc
    reference_nc = -(f[-2] - 8 * f[-1] + 8 * f[1] - f[2]) / (12 * e)
    fd_nc = FiniteDifferenceHVP()(atoms, v_nc)
    error = np.abs(fd_nc - reference_nc).max() / np.abs(reference_nc).max()
    assert error < 1e-7


def test_hvp_choice_is_pluggable():
    build = lambda: argon(2, 60)  # noqa: E731
    a_nc, b_nc = random_loss(build())
    run = WholeRun(build, 200, a_nc, b_nc)
    exact = run.gradients()
    calls = []

    def counted(atoms, v_nc):
        calls.append(1)
        return FiniteDifferenceHVP(1e-5)(atoms, v_nc)

    fd = run.gradients(hvp='finite-difference')
    custom = run.gradients(hvp=counted)
    assert len(calls) == custom.hessian_vector_products == 201
    for other in (fd, custom):
        np.testing.assert_allclose(other.positions, exact.positions,
                                   rtol=1e-6, atol=1e-6 * np.abs(
                                       exact.positions).max())


# -- bad input: clear errors, nothing lost --------------------------------

@pytest.mark.parametrize('call, error, match', [
    (lambda dyn, n: dyn.backpropagate(-1, np.zeros((n, 3))), ValueError,
     'steps'),
    (lambda dyn, n: dyn.backpropagate(5, np.zeros((n, 2))), ValueError,
     r'shape \(13, 3\)'),
    (lambda dyn, n: dyn.backpropagate(5, np.full((n, 3), np.nan)),
     ValueError, 'non-finite'),
    (lambda dyn, n: dyn.backpropagate(5, np.zeros((n, 3)),
                                      np.zeros((n + 1, 3))),
     ValueError, 'grad_momenta'),
    (lambda dyn, n: dyn.backpropagate(5, np.zeros((n, 3)), hvp='exact'),
     ValueError, 'hvp must be one of'),
    (lambda dyn, n: dyn.backpropagate(5, np.zeros((n, 3)),
                                      parameters=('rc',)),
     ValueError, 'epsilon'),
])
def test_bad_input_is_refused_before_anything_moves(call, error, match):
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(10)
    end = snapshot(atoms)
    with pytest.raises(error, match=match):
        call(dyn, len(atoms))
    assert_same_state(atoms, end)
    assert dyn.dt > 0
    dyn.backpropagate(10, np.zeros((len(atoms), 3)))
    assert_same_state(atoms, start)


def test_calculators_without_products_are_told_what_to_do():
    atoms = copper()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(3)
    with pytest.raises(ValueError, match='finite-difference'):
        dyn.backpropagate(3, np.zeros((len(atoms), 3)), hvp='analytic')
    with pytest.raises(ValueError, match='cannot differentiate'):
        dyn.backpropagate(3, np.zeros((len(atoms), 3)),
                          parameters=('epsilon',))


class FailingLennardJones(AseLennardJones):
    """ASE's LennardJones that raises on its n-th calculation."""

    def __init__(self, fail_at, **kwargs):
        super().__init__(**kwargs)
        self.count, self.fail_at = 0, fail_at

    def calculate(self, *args, **kwargs):
        self.count += 1
        if self.count == self.fail_at:
            raise RuntimeError('calculator failed')
        super().calculate(*args, **kwargs)


def test_a_failed_retrace_leaves_a_valid_reversible_state():
    atoms = argon(2, 60)
    atoms.calc = FailingLennardJones(10**9, epsilon=AR_EPSILON,
                                     sigma=AR_SIGMA, rc=8.5)
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(40)
    atoms.calc.fail_at = atoms.calc.count + 50  # mid-retrace
    with pytest.raises(RuntimeError, match='calculator failed'):
        dyn.backpropagate(40, np.ones((len(atoms), 3)))
    assert dyn.dt > 0
    remaining = round(dyn.get_time() / DT)
    assert 0 < remaining < 40
    dyn.backpropagate(remaining, np.ones((len(atoms), 3)))
    assert_same_state(atoms, start)


def test_zero_steps_returns_the_given_gradients():
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    a_nc, b_nc = random_loss(atoms)
    g = dyn.backpropagate(0, a_nc, b_nc)
    gx, gp = g
    assert np.array_equal(gx, a_nc) and np.array_equal(gp, b_nc)
    assert g.hessian_vector_products == 0


def test_gradients_unpack_as_a_pair_and_name_their_parts():
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(5)
    g = dyn.backpropagate(5, np.ones((len(atoms), 3)),
                          parameters=['epsilon', 'sigma'])
    gx, gp = g
    assert gx is g.positions and gp is g.momenta
    assert set(g.parameters) == {'epsilon', 'sigma'}


def test_no_product_is_spent_on_a_zero_momentum_adjoint():
    # A loss on positions only: the first kick of the retrace meets
    # a_p = 0, where H a_p = 0 needs no calculation.
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(10)
    g = dyn.backpropagate(10, np.ones((len(atoms), 3)))
    assert g.hessian_vector_products == 10
