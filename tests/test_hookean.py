"""ASE's Hookean constraint under the reversible integrators.

Hookean adds a restoring force of the positions alone (ASE's
``atoms.get_forces(md=True)`` adds it to the calculator's), so the kick
stays a function of the positions: runs go out and back bit for bit.  The
system is a Cu dimer on a fixed Pt(110) slab under ASE's EMT, each of
Hookean's three kinds stretched by a push on the outer Cu atom.
"""

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import fcc110
from ase.calculators.emt import EMT
from ase.constraints import FixAtoms, Hookean
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleLangevin, ReversibleVerlet

from exactness import assert_runs_back
from tiers import SLOW, tiered

DT = 2 * units.fs
STEPS = 100
#: Spring constant, eV/Å².
K = 15.0


def adsorbed_dimer(*springs):
    """Pt(110) slab (8 atoms, fixed) with a Cu dimer on top (atoms 8, 9);
    atom 9 pushed away from the surface; ``springs`` added as
    constraints."""
    atoms = fcc110('Pt', (2, 2, 2), vacuum=7.0)
    top = atoms[7].position
    atoms += Atoms('Cu2', positions=[top + (0.0, 0.0, 2.5),
                                     top + (0.0, 0.0, 5.0)])
    atoms.set_constraint([FixAtoms(indices=range(8)), *springs])
    momenta = np.zeros((len(atoms), 3))
    momenta[9] = (0.0, 2.0, 20.0)
    atoms.set_momenta(momenta)
    atoms.calc = EMT()
    return atoms


def spring(kind):
    """A Hookean of ``kind`` that the push stretches within a few steps."""
    if kind == 'bond':
        return Hookean(8, 9, k=K, rt=2.6)
    z9 = adsorbed_dimer()[9].position
    if kind == 'point':
        return Hookean(9, tuple(z9), k=K, rt=0.3)
    # The plane z = z9 + 0.3 Å, normal up: pulls atom 9 down above it.
    return Hookean(9, (0.0, 0.0, 1.0, -(z9[2] + 0.3)), k=K)


KINDS = ('bond', 'point', 'plane')


def largest_spring_energy(dyn, constraint):
    """A list that gets Hookean's energy (eV) at every step of ``dyn``."""
    energies = []
    dyn.attach(lambda: energies.append(
        constraint.adjust_potential_energy(dyn.atoms)))
    return energies


@pytest.mark.parametrize('kind', KINDS)
@pytest.mark.parametrize('dynamics', tiered(['verlet', 'langevin'],
                                            quick=['verlet']))
def test_out_and_back_bit_for_bit(kind, dynamics):
    constraint = spring(kind)
    atoms = adsorbed_dimer(constraint)
    if dynamics == 'verlet':
        dyn = ReversibleVerlet(atoms, DT)
    else:
        dyn = ReversibleLangevin(atoms, DT, temperature_K=300,
                                 friction=0.01 / units.fs, fixcm=False,
                                 seed=7)
    energies = largest_spring_energy(dyn, constraint)
    assert_runs_back(dyn, STEPS)
    # The spring pulled: without it the run would not be this test.
    assert max(energies) > 0.05


@SLOW
@pytest.mark.parametrize('kind', KINDS)
def test_follows_ase_velocity_verlet(kind):
    # Physics, not exactness: ASE's float integrator with the same
    # constraint stays within rounding of the grid's trajectory.
    ours = adsorbed_dimer(spring(kind))
    theirs = adsorbed_dimer(spring(kind))
    ReversibleVerlet(ours, DT).run(STEPS)
    VelocityVerlet(theirs, DT).run(STEPS)
    assert np.allclose(ours.positions, theirs.positions, rtol=0, atol=1e-8)
    assert np.allclose(ours.get_momenta(), theirs.get_momenta(), rtol=0,
                       atol=1e-8)


def test_ase_hookean_checks_pass():
    # ASE's own checks of Hookean in NVE dynamics: the bond is kept, the
    # atom stays below the plane, the total energy (spring included) is
    # conserved; with a bond and a plane spring at once.
    atoms = adsorbed_dimer(Hookean(8, 9, k=K, rt=2.6),
                           Hookean(8, (0.0, 0.0, 1.0, -15.0), k=K))
    dyn = ReversibleVerlet(atoms, units.fs)
    energies = []
    dyn.attach(lambda: energies.append(atoms.get_total_energy()))
    dyn.run(STEPS)
    assert np.linalg.norm(atoms[8].position - atoms[9].position) < 3.0
    assert atoms[9].z < 15.0
    assert max(energies) - min(energies) < 0.01


def test_energy_check_counts_the_spring_energy_once():
    # The spring takes up more than an eV; a check every step with a
    # tolerance of 0.02 eV passes only if the energy it watches is the
    # calculator's plus Hookean's (as ASE's get_potential_energy gives).
    constraint = spring('point')
    atoms = adsorbed_dimer(constraint)
    dyn = ReversibleVerlet(atoms, units.fs, energy_check=1,
                           energy_tolerance=0.02)
    energies = largest_spring_energy(dyn, constraint)
    dyn.run(STEPS)
    assert max(energies) > 1.0
    calc_only = atoms.get_potential_energy(apply_constraint=False)
    assert atoms.get_potential_energy() == \
        calc_only + constraint.adjust_potential_energy(atoms)


def whole_run_loss(kind, x0_nc, a_nc, b_nc, steps):
    """``a . x + b . p`` after ``steps`` of ASE's VelocityVerlet from the
    start positions ``x0_nc`` (float: a smooth function of them)."""
    atoms = adsorbed_dimer(spring(kind))
    atoms.positions = x0_nc
    VelocityVerlet(atoms, DT).run(steps)
    return np.vdot(a_nc, atoms.positions) + np.vdot(b_nc, atoms.get_momenta())


@pytest.mark.parametrize('kind', KINDS)
def test_gradients_include_the_spring(kind):
    # The adjoint's products come from the calculator, which knows nothing
    # of Hookean: the kick's adjoint adds the spring's part.  Checked
    # against central differences of ASE's float run (the grid's run
    # follows it to ~1e-11 Å over these steps).
    steps = 40
    atoms = adsorbed_dimer(spring(kind))
    dyn = ReversibleVerlet(atoms, DT)
    x0_nc = atoms.positions.copy()
    energies = largest_spring_energy(dyn, atoms.constraints[1])
    dyn.run(steps)
    assert max(energies) > 0.05
    rng = np.random.default_rng(3)
    a_nc, b_nc = rng.normal(size=(2, len(atoms), 3))
    g = dyn.backpropagate(steps, a_nc, b_nc)
    u_nc = np.zeros_like(x0_nc)
    u_nc[8:] = rng.normal(size=(2, 3))  # the free atoms
    h = 1e-5
    reference = (whole_run_loss(kind, x0_nc + h * u_nc, a_nc, b_nc, steps)
                 - whole_run_loss(kind, x0_nc - h * u_nc, a_nc, b_nc,
                                  steps)) / (2 * h)
    assert abs(np.vdot(g.positions, u_nc) - reference) \
        < 1e-6 * abs(reference)


def test_a_spring_added_between_runs_pulls_from_the_next_step():
    # Forces are kept per position value: a new constraint must not leave
    # the spring out of forces computed before it was added.
    atoms = adsorbed_dimer()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(10)
    with pytest.warns(Warning, match='the constraints'):
        atoms.set_constraint([FixAtoms(indices=range(8)), spring('point')])
        theirs = atoms.copy()
        dyn.run(STEPS)
    theirs.calc = EMT()
    VelocityVerlet(theirs, DT).run(STEPS)
    assert np.allclose(atoms.positions, theirs.positions, rtol=0, atol=1e-8)
