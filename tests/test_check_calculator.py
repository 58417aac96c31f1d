"""check_calculator: one call tells a user whether their forces are exact,
which purity mode applies and what it costs -- and it agrees with what the
integrator then does."""

import numpy as np
import pytest
from ase import units
from ase.build import molecule
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as AseLJ
from ase.calculators.singlepoint import SinglePointCalculator
from ase.calculators.tip3p import TIP3P
from ase.constraints import FixBondLengths

from ase_reversible import (CoarseQuantumError, LennardJones,
                            ReversibleVerlet, UnsupportedConstraintError,
                            check_calculator)
from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,
                                        argon_cluster, argon_lj, copper_bulk,
                                        thermalize)

from conftest import needs_asap3
from warm_start import WarmStart

DT = 5 * units.fs


class WarmStartedLJ(WarmStart, AseLJ):
    """ASE's LennardJones with the history of an SCF."""


def checked(atoms, **kwargs):
    """The check, and proof that it left the atoms as they were."""
    x_nc, p_nc = atoms.get_positions(), atoms.get_momenta()
    report = check_calculator(atoms, **kwargs)
    assert np.array_equal(atoms.positions, x_nc)
    assert np.array_equal(atoms.get_momenta(), p_nc)
    return report


def run_back(atoms, steps=40):
    dyn = ReversibleVerlet(atoms, DT)
    start = dyn.state
    dyn.run(steps)
    dyn.reverse().run(steps)
    assert np.array_equal(dyn.state.ix_nc, start.ix_nc)
    assert np.array_equal(dyn.state.ip_nc, start.ip_nc)
    return dyn


@pytest.mark.parametrize('build, calc, mode', [
    (lambda: argon_cluster(3, 100), argon_lj, 'sorted'),
    (lambda: copper_bulk((2, 2, 2)), EMT, 'sorted'),
    (lambda: argon_cluster(3, 100),
     lambda: LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC),
     'trust'),
], ids=['ase-lj', 'ase-emt', 'own-lj'])
def test_exact_calculators_are_reported_with_the_mode_the_integrator_uses(
        build, calc, mode):
    atoms = build()
    atoms.calc = calc()
    report = checked(atoms)
    assert report.exact and report.mode == mode and report.advice is None
    assert report.probe_noise == 0.0
    assert mode in str(report)
    assert run_back(atoms).force_purity.mode == mode


def test_asap3_is_guarded_and_the_precision_price_is_the_integrators():
    asap3 = needs_asap3()
    atoms = copper_bulk((3, 3, 3))
    atoms.calc = asap3.EMT()
    report = checked(atoms, timestep=DT)
    assert report.exact and report.mode == 'guarded'
    dyn = run_back(atoms)
    # The quantum the report names is the one the integrator chose.
    assert f'{dyn.grid.momentum_quantum:.3g}' in report.cost


def test_history_dependent_forces_are_refused_with_the_remedy():
    atoms = argon_cluster(2, 50)
    atoms.calc = WarmStartedLJ(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    report = checked(atoms)
    assert not report.exact and report.mode is None
    assert 'from scratch' in report.advice


def test_no_calculator_is_an_error():
    with pytest.raises(RuntimeError, match='attach one'):
        check_calculator(argon_cluster(2, 50))


def two_waters():
    """Two TIP3P water molecules in vacuum, thermal (O, H, H each)."""
    atoms = molecule('H2O')
    other = atoms.copy()
    other.translate([3.0, 0.2, 0.1])
    atoms += other
    atoms.center(vacuum=4.0)
    thermalize(atoms, 300, 0)
    atoms.calc = TIP3P(rc=4.0)
    return atoms


def assert_refused_as_the_integrator_refuses(atoms, error_class, **kwargs):
    report = checked(atoms, **kwargs)
    with pytest.raises(error_class) as raised:
        ReversibleVerlet(atoms, kwargs.get('timestep', DT),
                         force_noise=kwargs.get('force_noise'))
    assert not report.exact and report.mode is None
    assert report.refused_by == error_class.__name__
    assert report.advice == str(raised.value)
    assert error_class.__name__ in str(report)
    return report


def test_a_constraint_the_integrators_refuse_is_refused_here_too():
    atoms = two_waters()
    # Without the constraint, the verdict is the integrator's, and true.
    report = checked(atoms)
    assert report.exact and report.mode == 'trust'
    assert run_back(atoms, steps=10).force_purity.mode == 'trust'
    # Rigid water (three bonds a molecule) runs; a chain of two bonds,
    # which leaves the angle free, is refused by both.
    atoms.constraints = FixBondLengths(
        [(3 * i + j, 3 * i + (j + 1) % 3) for i in range(2) for j in range(3)])
    report = checked(atoms)
    assert report.exact and report.mode == 'trust'
    assert run_back(atoms, steps=10).force_purity.mode == 'trust'
    atoms.constraints = FixBondLengths(
        [(3 * i + j, 3 * i + j + 1) for i in range(2) for j in range(2)])
    report = assert_refused_as_the_integrator_refuses(
        atoms, UnsupportedConstraintError)
    assert 'FixBondLengths joins atoms [0, 1, 2] by 2 bonds' in report.advice


def test_a_momentum_quantum_the_integrator_refuses_is_refused_here_too():
    # A force_noise this large raises the momentum quantum past what the
    # thermal momenta can bear; the refusal needs the time step.
    atoms = argon_cluster(2, 50)
    atoms.calc = argon_lj()
    assert checked(atoms, force_noise=1e-3).mode == 'guarded'
    assert_refused_as_the_integrator_refuses(
        atoms, CoarseQuantumError, timestep=DT, force_noise=1e-3)


def test_stored_results_are_refused_as_the_integrator_refuses_them():
    atoms = argon_cluster(2, 50)
    atoms.calc = SinglePointCalculator(atoms, energy=0.0,
                                       forces=np.zeros((len(atoms), 3)))
    assert_refused_as_the_integrator_refuses(atoms, RuntimeError)


def test_tblite_on_two_threads_gets_the_same_verdict_every_call():
    pytest.importorskip('tblite', reason='tblite is not installed (it is in '
                        "the test extra: pip install '.[test]')")
    from threadpoolctl import threadpool_limits
    from tblite.ase import TBLite
    atoms = molecule('CH3CH2OH')
    atoms.center(vacuum=5.0)
    thermalize(atoms, 300, 0)
    atoms.calc = TBLite(method='GFN2-xTB', verbosity=0)
    # Two OpenMP threads whatever the environment says: their sums vary
    # from call to call unless the check holds them to one.
    with threadpool_limits(limits=2, user_api='openmp'):
        reports = [checked(atoms) for _ in range(3)]
    for report in reports:
        assert report.exact and report.mode == 'cold-start'
        assert report.probe_noise == 0.0
        assert 'one thread' in report.cost
