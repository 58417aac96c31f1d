"""The package's LennardJones: derivatives, purity, agreement with ASE's."""

import numpy as np
import pytest
from ase.build import bulk
from ase.calculators.fd import calculate_numerical_stress
from ase.calculators.lj import LennardJones as AseLennardJones
from ase.cluster import Icosahedron

from ase_reversible import LennardJones, ReversibleVerlet, probe_purity

from conftest import AR_EPSILON, AR_SIGMA, DT, thermalize
from exactness import assert_same_state, forward_and_back
from finite_differences import at_positions, central_difference


def lj(**kwargs):
    return LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA, **kwargs)


def rattled_cluster(seed=1):
    atoms = Icosahedron('Ar', 3, latticeconstant=5.26)
    atoms.rattle(0.15, seed=seed)
    atoms.calc = lj()
    return atoms


def rattled_crystal(seed=2):
    atoms = bulk('Ar', 'fcc', a=5.26) * (3, 3, 3)
    atoms.rattle(0.15, seed=seed)
    atoms.calc = lj()
    return atoms


@pytest.mark.parametrize('build', [rattled_cluster, rattled_crystal])
def test_forces_are_minus_the_energy_gradient(build):
    atoms = build()
    x_nc = atoms.positions.copy()
    f_nc = atoms.get_forces()
    v_nc = np.random.default_rng(0).normal(size=x_nc.shape)
    slope = central_difference(at_positions(atoms, atoms.get_potential_energy),
                               x_nc, v_nc, 1e-5)
    # Truncation ~h² |E'''| and cancellation ~1e-16 |E| / h: both ~1e-10
    # relative here.
    assert slope == pytest.approx(-np.vdot(f_nc, v_nc), rel=1e-7)


@pytest.mark.parametrize('build', [rattled_cluster, rattled_crystal])
def test_hessian_vector_product_matches_finite_differences(build):
    atoms = build()
    x_nc = atoms.positions.copy()
    v_nc = np.random.default_rng(1).normal(size=x_nc.shape)
    hv_nc = atoms.calc.hessian_vector_product(atoms, v_nc)
    minus_fd_nc = central_difference(at_positions(atoms, atoms.get_forces),
                                     x_nc, v_nc, 1e-5)
    error = np.abs(hv_nc + minus_fd_nc).max() / np.abs(hv_nc).max()
    assert error < 1e-7


def test_hessian_is_symmetric():
    atoms = rattled_crystal()
    rng = np.random.default_rng(2)
    v_nc, w_nc = rng.normal(size=(2, len(atoms), 3))
    hvp = atoms.calc.hessian_vector_product
    assert np.vdot(w_nc, hvp(atoms, v_nc)) == pytest.approx(
        np.vdot(v_nc, hvp(atoms, w_nc)), rel=1e-12)


@pytest.mark.parametrize('name', ['epsilon', 'sigma'])
def test_force_parameter_derivatives_match_finite_differences(name):
    atoms = rattled_cluster()
    derivative_nc = atoms.calc.force_parameter_derivative(atoms, name)
    value = atoms.calc.parameters[name]
    h = 1e-6 * value

    def forces_at(theta):
        # The cut-offs are held fixed, as the derivative assumes.
        calc = lj(rc=3 * AR_SIGMA)
        calc.set(**{name: theta})
        return calc.get_forces(atoms)

    fd_nc = (forces_at(value + h) - forces_at(value - h)) / (2 * h)
    error = np.abs(derivative_nc - fd_nc).max() / np.abs(derivative_nc).max()
    assert error < 1e-7


def test_matches_ase_lennard_jones_inside_the_switch():
    # With the switch moved beyond every pair, the potential is plain
    # Lennard-Jones; ASE's shifts its energy by the pair energy at rc.
    atoms = rattled_cluster()
    ours = atoms.copy()
    ours.calc = lj(rc=100.0, ro=99.0)
    ase = atoms.copy()
    ase.calc = AseLennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA, rc=100.0)
    pairs = len(atoms) * (len(atoms) - 1) / 2
    shift = 4 * AR_EPSILON * ((AR_SIGMA / 100)**12 - (AR_SIGMA / 100)**6)
    assert ours.get_potential_energy() == pytest.approx(
        ase.get_potential_energy() + pairs * shift, abs=1e-12)
    np.testing.assert_allclose(ours.get_forces(), ase.get_forces(),
                               rtol=1e-12, atol=1e-14)


def test_stress_matches_finite_differences():
    atoms = rattled_crystal()
    numerical = calculate_numerical_stress(atoms, eps=1e-6)
    np.testing.assert_allclose(atoms.get_stress(), numerical, rtol=1e-6,
                               atol=1e-9)


def test_forces_are_continuous_through_the_switch():
    atoms = rattled_cluster()
    ro, rc = atoms.calc.cutoffs
    dimer = atoms[:2]
    dimer.calc = lj()
    forces = []
    for r in (ro - 1e-9, ro + 1e-9, rc - 1e-9, rc + 1e-9):
        dimer.positions = [[0, 0, 0], [r, 0, 0]]
        forces.append(dimer.get_forces()[0, 0])
    assert forces[0] == pytest.approx(forces[1], abs=1e-10)
    assert abs(forces[2]) < 1e-12 and forces[3] == 0.0


@pytest.mark.parametrize('build', [rattled_cluster, rattled_crystal])
def test_forces_do_not_depend_on_history(build):
    atoms = build()
    assert probe_purity(atoms, trials=3) == 0.0


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match='sigma'):
        LennardJones(sigma=-1.0)
    with pytest.raises(ValueError, match='ro < rc'):
        LennardJones(sigma=1.0, rc=2.0, ro=3.0)
    with pytest.raises(ValueError, match='available'):
        rattled_cluster().calc.force_parameter_derivative(rattled_cluster(),
                                                          'rc')


def test_reversible_verlet_trusts_it_and_reverses_exactly():
    atoms = thermalize(Icosahedron('Ar', 3, latticeconstant=5.26), 120)
    atoms.calc = lj()
    dyn = ReversibleVerlet(atoms, DT)
    assert dyn.force_purity.mode == 'trust'
    start, moved = forward_and_back(dyn, 2000)
    assert moved
    assert_same_state(atoms, start)


def test_moves_below_ase_tolerance_are_seen():
    # ASE's default state check ignores moves under 1e-15 Å; a fine
    # fixed-point grid makes such moves.
    atoms = rattled_cluster()
    atoms.get_forces()
    atoms.positions[0, 0] = np.nextafter(atoms.positions[0, 0], np.inf)
    assert atoms.calc.check_state(atoms) == ['positions']
    atoms.get_forces()
    assert atoms.calc.check_state(atoms) == []
