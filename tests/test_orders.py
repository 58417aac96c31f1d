"""Higher-order compositions: exact reversal, cost, and convergence order."""

import math

import numpy as np
import pytest
from ase import units
from ase.calculators.lj import LennardJones

from ase_reversible import ReversibleVerlet
from ase_reversible.core.compositions import (COMPOSITIONS, DEFAULT_FOR_ORDER,
                                         composition_for)

from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, CALCULATORS, DT, argon_bulk,
                      argon_cluster, copper_bulk)
from exactness import assert_runs_back
from tiers import SLOW, tiered
from test_ase_contract import CountingLennardJones

ORDERS = sorted(DEFAULT_FOR_ORDER)
SCHEMES = ['velocity', 'position']

# (builder, calculator, steps each way); fewer steps for the costly orders.
CASES = {
    'Ar13 hot ase-lj': (lambda: argon_cluster(2, 120), 'ase-lj', 60),
    'Ar bulk asap-lj': (lambda: argon_bulk((4, 4, 4), 80), 'asap-lj', 60),
    'Cu500 bulk asap-emt': (lambda: copper_bulk((5, 5, 5), 600), 'asap-emt',
                            40),
    'Cu32 bulk ase-emt': (lambda: copper_bulk((2, 2, 2), 600), 'ase-emt', 8),
}


@pytest.mark.parametrize('scheme', SCHEMES)
@pytest.mark.parametrize('order', ORDERS)
@pytest.mark.parametrize('case', list(CASES))
def test_every_order_reverses_exactly(case, order, scheme):
    build, calc, steps = CASES[case]
    atoms = build()
    atoms.calc = CALCULATORS[calc]()
    dyn = ReversibleVerlet(atoms, DT, scheme=scheme, order=order)
    assert_runs_back(dyn, max(2, steps * 2 // order))


@pytest.mark.parametrize('name', sorted(COMPOSITIONS))
def test_every_named_composition_reverses_exactly(name):
    atoms = argon_cluster(2, 120)
    atoms.calc = CALCULATORS['asap-lj']()
    dyn = ReversibleVerlet(atoms, DT, order=COMPOSITIONS[name].order,
                           composition=name)
    assert_runs_back(dyn, 40)


def test_custom_palindrome_reverses_exactly():
    atoms = argon_cluster(2, 120)
    atoms.calc = CALCULATORS['asap-lj']()
    dyn = ReversibleVerlet(atoms, DT, composition=[0.3, 0.4, 0.3])
    assert_runs_back(dyn, 50)


@pytest.mark.parametrize('scheme', SCHEMES)
@pytest.mark.parametrize('order', ORDERS)
def test_force_calls_per_step_equal_the_stages(order, scheme):
    def calculations(steps):
        atoms = argon_cluster(2, 80)
        atoms.calc = CountingLennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                          rc=AR_RC)
        # Without the energy check, whose cost test_ase_contract counts.
        ReversibleVerlet(atoms, DT, scheme=scheme, order=order,
                         energy_check=0).run(steps)
        return atoms.calc.calculations

    stages = composition_for(order).stages
    assert calculations(6) - calculations(3) == 3 * stages


# -- convergence ---------------------------------------------------------------

SMOOTH_TIME = 2000 * units.fs


def energy_error(order, timestep_fs, scheme='velocity'):
    """Largest |E(t) - E(0)| / |E(0)| over 2 ps of a cold Ar13 cluster.

    The cutoff (12 Å) exceeds every distance in the cluster, so the
    potential is smooth along the whole path and the error follows the
    nominal order until the fixed-point floor (~1e-11) is reached.
    """
    atoms = argon_cluster(2, 30)
    atoms.calc = LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=12.0)
    dyn = ReversibleVerlet(atoms, timestep_fs * units.fs, scheme=scheme,
                           order=order)
    e0 = atoms.get_total_energy()
    errors = []
    dyn.attach(lambda: errors.append(abs(atoms.get_total_energy() - e0)))
    dyn.run(round(SMOOTH_TIME / (timestep_fs * units.fs)))
    return max(errors) / abs(e0)


# Step pairs (fs) where the error is above the floor and in its asymptotic
# regime; measured on this system: observed orders 2.00, 3.98, 6.00, 7.64,
# 9.02.
CONVERGENCE_STEPS = {2: (20, 10), 4: (20, 10), 6: (80, 40), 8: (80, 40),
                     10: (80, 40)}


@pytest.mark.parametrize('order', tiered(ORDERS, quick=[2, 4]))
def test_energy_error_converges_with_the_nominal_order(order):
    coarse, fine = CONVERGENCE_STEPS[order]
    observed = math.log2(energy_error(order, coarse)
                         / energy_error(order, fine)) / math.log2(coarse / fine)
    assert abs(observed - order) < 0.5 + 0.1 * order  # 0.7 at 2, 1.5 at 10


@SLOW
def test_position_scheme_order_four_converges_with_order_four():
    observed = math.log2(energy_error(4, 20, 'position')
                         / energy_error(4, 10, 'position'))
    assert abs(observed - 4) < 0.5


def test_higher_order_is_more_accurate_at_the_same_step():
    errors = [energy_error(order, 40) for order in (2, 4, 6)]
    assert errors[0] > 100 * errors[1] > 100 * 10 * errors[2]


# -- bad input -----------------------------------------------------------------

@pytest.mark.parametrize('order', [1, 3, 12, 4.0, '4', True])
def test_unknown_order_is_refused(order):
    atoms = argon_cluster(2, 80)
    atoms.calc = CALCULATORS['asap-lj']()
    with pytest.raises(ValueError, match='order must be one of'):
        ReversibleVerlet(atoms, DT, order=order)


@pytest.mark.parametrize('composition, message', [
    ('kahan-li-9', 'is of order 6'),
    ('no-such-scheme', 'unknown composition'),
    ([0.2, 0.5, 0.3], 'read the same backwards'),
    ([0.5, 0.6, 0.5], 'sum to 1'),
    ([0.5, float('nan'), 0.5], 'finite'),
])
def test_bad_composition_is_refused(composition, message):
    atoms = argon_cluster(2, 80)
    atoms.calc = CALCULATORS['asap-lj']()
    with pytest.raises(ValueError, match=message):
        ReversibleVerlet(atoms, DT, order=4, composition=composition)


def test_todict_names_the_order_and_composition():
    atoms = argon_cluster(2, 80)
    atoms.calc = CALCULATORS['asap-lj']()
    d = ReversibleVerlet(atoms, DT, order=6).todict()
    assert (d['order'], d['composition']) == (6, 'kahan-li-9')


def test_compositions_are_palindromes_that_sum_to_one():
    for c in COMPOSITIONS.values():
        assert c.fractions == c.fractions[::-1]
        assert math.isclose(math.fsum(c.fractions), 1.0, abs_tol=1e-15)
    assert np.array_equal([c.stages for c in map(composition_for, ORDERS)],
                          [1, 5, 9, 15, 33])
