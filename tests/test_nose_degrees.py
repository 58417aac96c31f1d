"""ReversibleNose's degrees of freedom, against ASE's NVT statistics test,
and a start from rest.

The statistics are those of ASE's own test of ``NoseHooverChainNVT`` (4 Au
atoms with asap3's EMT equilibrated at 300 K and 5000 bar, 20 fs steps,
tdamp 1000 fs, the temperature read every 5 steps 2000 times, its mean
within ``0.67 / N`` of the target); the system is built here.  N_f is
ASE's count: 3N for free atoms, at rest or not, as ASE's class
thermostats them; 3N - 3 with FixCom.
"""

import warnings

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.constraints import FixCom, Hookean
from ase.md.nptberendsen import NPTBerendsen
from ase.md.velocitydistribution import (MaxwellBoltzmannDistribution,
                                         Stationary)

from ase_reversible import ReversibleNose, UnstableIntegrationError

from conftest import CALCULATORS, argon_cluster, needs_asap3
from tiers import SLOW

TARGET_K = 300.0


def gold4(centre_moves=False, fixcom=False):
    """ASE's start: 4 Au equilibrated by its NPTBerendsen from momenta at
    300 K and at rest; ``centre_moves`` then gives the centre a thermal
    velocity (1.5 kT on average), ``fixcom`` adds FixCom."""
    asap3 = needs_asap3()
    atoms = bulk('Au', cubic=True)
    atoms.calc = asap3.EMT()
    with warnings.catch_warnings():  # deprecated in ASE 3.29, kept in all
        warnings.simplefilter('ignore', DeprecationWarning)
        MaxwellBoltzmannDistribution(atoms, temperature_K=TARGET_K,
                                     force_temp=True,
                                     rng=np.random.RandomState(42))
    Stationary(atoms)
    with NPTBerendsen(atoms, timestep=20 * units.fs, temperature_K=TARGET_K,
                      pressure_au=5000 * units.bar, taut=1000 * units.fs,
                      taup=1000 * units.fs,
                      compressibility_au=1 / (220 * units.GPa)) as md:
        md.run(1000)
    if centre_moves:
        m_n = atoms.get_masses()
        v_c = np.random.default_rng(7).normal(size=3) * np.sqrt(
            units.kB * TARGET_K / m_n.sum())
        atoms.set_momenta(atoms.get_momenta() + m_n[:, None] * v_c)
    if fixcom:
        atoms.set_constraint(FixCom())
    return atoms


def mean_temperature(atoms, centre_moves=False):
    """``(N_f, <T>)``: ASE's test's run and mean of
    ``atoms.get_temperature()`` (over ASE's degrees of freedom)."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore' if centre_moves else 'error',
                              UserWarning)
        dyn = ReversibleNose(atoms, 20 * units.fs, TARGET_K,
                             1000 * units.fs)
    temperatures = []
    for _ in range(2000):
        dyn.run(5)
        temperatures.append(atoms.get_temperature())
    return dyn.degrees_of_freedom, float(np.mean(temperatures))


@SLOW
@pytest.mark.parametrize('centre_moves', [False, True],
                         ids=['at-rest', 'moving-centre'])
def test_ases_nvt_statistics_test_passes(centre_moves):
    """ASE's start (at rest, as its test has it) and one with a thermal
    centre: 3N are thermostatted, as by ASE's NoseHooverChainNVT, and <T>
    over 3N is the target within ASE's 0.67 / N (ASE's own assertion)."""
    atoms = gold4(centre_moves=centre_moves)
    n = len(atoms)
    dof, mean_K = mean_temperature(atoms, centre_moves)
    assert dof == 3 * n
    assert abs(mean_K - TARGET_K) < 0.67 / n * TARGET_K


@SLOW
def test_with_fixcom_the_internal_motion_is_at_the_target():
    """With FixCom the centre is held at rest and 3N - 3 are thermostatted:
    <T> over ASE's 3N - 3 is the target within ASE's 0.67 / N."""
    atoms = gold4(fixcom=True)
    n = len(atoms)
    dof, mean_K = mean_temperature(atoms)
    assert dof == 3 * n - 3
    assert abs(mean_K - TARGET_K) < 0.67 / n * TARGET_K


def ar13(**spring):
    atoms = argon_cluster(2, 60)
    Stationary(atoms)
    atoms.calc = CALCULATORS['ase-lj']()
    if spring:
        atoms.set_constraint(Hookean(**spring))
    return atoms


@pytest.mark.parametrize('spring', [
    {}, {'a1': 0, 'a2': 1, 'rt': 3.0, 'k': 1.0},
    {'a1': 0, 'a2': (0.0, 0.0, 0.0), 'rt': 1.0, 'k': 1.0},
    {'a1': 0, 'a2': (0.0, 0.0, 1.0, -5.0), 'k': 1.0},
], ids=['free', 'spring-between-atoms', 'spring-to-a-point',
        'spring-to-a-plane'])
def test_free_atoms_at_rest_count_3n_with_or_without_springs(spring):
    """ASE's count: a centre at rest is thermostatted too, whether or not a
    Hookean spring pulls the total momentum away from zero."""
    atoms = ar13(**spring)
    assert ReversibleNose(atoms, 5 * units.fs, 60,
                          100 * units.fs).degrees_of_freedom == 3 * 13


def test_a_record_without_its_count_resumes_leaving_the_centre_out():
    """A frame written when a centre at rest was left out of N_f (its
    record has no 'degrees_of_freedom') resumes with 3N - 3, so it goes on
    as that run would have (test_nose's digests of the single thermostat
    check its bits); the record written now resumes with 3N."""
    steps = []
    for strip in (False, True):
        atoms = ar13()
        ReversibleNose(atoms, 5 * units.fs, 60, 100 * units.fs).run(3)
        if strip:
            del atoms.info['reversible']['nose']['degrees_of_freedom']
        dyn = ReversibleNose(atoms, 5 * units.fs, 60, 100 * units.fs)
        assert dyn.degrees_of_freedom == 3 * 13 - (3 if strip else 0)
        dyn.run(20)
        steps.append(dyn.counts)
    assert not np.array_equal(steps[0]['momentum'], steps[1]['momentum'])


def test_atoms_at_rest_are_told_to_get_thermal_momenta():
    """Nosé's thermostat scales momenta: zero stays zero and s falls to
    zero whatever tdamp; the warning and the error name the remedy."""
    atoms = bulk('Cu', cubic=True) * (2, 2, 2)
    atoms.calc = CALCULATORS['ase-emt']()
    with pytest.warns(UserWarning, match='MaxwellBoltzmannDistribution'):
        dyn = ReversibleNose(atoms, 5 * units.fs, 300, 100 * units.fs)
    start = dyn.counts
    with pytest.raises(UnstableIntegrationError,
                       match='Give the atoms thermal momenta first'):
        dyn.run(200)
    taken = dyn.nsteps
    assert 0 < taken < 200
    dyn.reverse().run(taken)
    for name, counts in start.items():
        assert np.array_equal(dyn.counts[name], counts), name
