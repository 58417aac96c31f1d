"""check_calculator: one call tells a user whether their forces are exact,
which purity mode applies and what it costs -- and it agrees with what the
integrator then does."""

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as AseLJ

from ase_reversible import (LennardJones, ReversibleVerlet, check_calculator)
from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,
                                        argon_cluster, argon_lj, copper_bulk)

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
