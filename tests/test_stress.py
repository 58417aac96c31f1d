"""Stress: time steps past stability, evaporation, close contacts, diffusion.

Every scene is checked to be extreme (a control on the physics: energies
exploding in VelocityVerlet, atoms gone beyond the cutoff, forces of
thousands of eV/Å, displacements of several cell lengths), and the
integrator either runs back bit for bit or stops with a clear error at a
state that still runs back bit for bit.  benchmarks/stress.py measures the
same scenes at length.
"""

import numpy as np
import pytest
from ase import Atoms, units
from ase.build import bulk
from ase.md.verlet import VelocityVerlet

from ase_reversible import (QuantumRangeError,
                            ReversibleVerlet, UnstableIntegrationError)
from ase_reversible.md.verlet import ENERGY_CHECK_INTERVAL
from conftest import (AR_RC, AR_SIGMA, CALCULATORS, DT, argon_cluster,
                      copper_bulk, thermalize)
from exactness import (assert_atoms_show_committed_state, assert_same_state,
                       run_back, run_until_refused, snapshot)
from tiers import SLOW

CU_BOND = 3.61 / np.sqrt(2)  # nearest-neighbour distance of ase.build's Cu


def with_calc(atoms, name):
    atoms.calc = CALCULATORS[name]()
    return atoms


def kinetic_energy(atoms):
    return float((atoms.get_momenta()**2
                  / atoms.get_masses()[:, None]).sum() / 2)


def velocity_verlet_energy_error(atoms, dt, steps):
    """Largest |E - E0| of VelocityVerlet over ``steps``; it never raises."""
    dyn = VelocityVerlet(atoms, dt)
    energies = []
    dyn.attach(lambda: energies.append(atoms.get_total_energy()))
    with np.errstate(all='ignore'):
        dyn.run(steps)
    return float(np.max(np.abs(np.array(energies) - energies[0])))


# -- time steps past the stability limit -------------------------------------

@pytest.mark.parametrize('scheme', ['velocity', 'position'])
def test_time_step_past_stability_stops_with_a_range_error(scheme):
    def cluster():
        return with_calc(argon_cluster(2, 40), 'ase-lj')

    dt, steps = 200 * units.fs, 30
    k0 = kinetic_energy(cluster())
    # Control: at this step VelocityVerlet blows up without a word.
    assert velocity_verlet_energy_error(cluster(), dt, steps) > 1e6 * k0

    # The energy check would stop it first (below): without it, the range.
    dyn = ReversibleVerlet(cluster(), dt, scheme=scheme, energy_check=0)
    start = snapshot(dyn.atoms)
    with np.errstate(all='ignore'):
        with pytest.raises(QuantumRangeError,
                           match='outside the fixed-point range.*'
                                 'The step was not taken'):
            dyn.run(steps)
    done = dyn.nsteps
    assert done < steps
    assert_atoms_show_committed_state(dyn)
    run_back(dyn, done, start)


@pytest.mark.parametrize('energy_check', [0, ENERGY_CHECK_INTERVAL])
def test_copper_blow_up_under_asap3_is_stopped_reversibly(energy_check):
    # asap3 forces are guarded, which coarsens the momentum quantum until
    # the momentum range is far beyond any blow-up: without the energy
    # check, the position range is what stops the run.
    def copper():
        return with_calc(copper_bulk((3, 3, 3), 300), 'asap-emt')

    dt, steps = 40 * units.fs, 100
    k0 = kinetic_energy(copper())
    assert velocity_verlet_energy_error(copper(), dt, steps) > 1e6 * k0

    dyn = ReversibleVerlet(copper(), dt, energy_check=energy_check)
    start = snapshot(dyn.atoms)
    if energy_check:
        with pytest.raises(UnstableIntegrationError):
            dyn.run(steps)
        assert 0 < dyn.nsteps <= 4  # caught by one of the first checks
    else:
        with pytest.raises(QuantumRangeError,
                           match='^position (increment )?of atom [0-9]+ is '
                                 'outside the fixed-point range'):
            dyn.run(steps)
    done = dyn.nsteps
    assert 0 < done < steps
    assert_atoms_show_committed_state(dyn)
    run_back(dyn, done, start)


def energy_trace(atoms, dt, steps, **kwargs):
    """Total energies after steps 0..k of an unchecked run (up to
    ``steps``, or until the range stops it), and the run."""
    dyn = ReversibleVerlet(atoms, dt, energy_check=0, **kwargs)
    energies = [atoms.get_total_energy()]
    with np.errstate(all='ignore'):
        try:
            for _ in dyn.irun(steps):
                if dyn.nsteps > len(energies) - 1:
                    energies.append(atoms.get_total_energy())
        except QuantumRangeError:
            pass
    return np.array(energies), dyn


BLOW_UPS = {
    # A slow drift (the energy creeps past the tolerance after ~370 steps),
    # a blow-up after a dozen steps, one at once; and asap3 copper
    # heating over ~70 steps, where reading the energy costs a force call.
    'Ar55 100 fs': (lambda: with_calc(argon_cluster(3, 40), 'ase-lj'), 100),
    'Ar55 120 fs': (lambda: with_calc(argon_cluster(3, 40), 'ase-lj'), 120),
    'Ar13 200 fs': (lambda: with_calc(argon_cluster(2, 40), 'ase-lj'), 200),
    'Cu108 30 fs': (lambda: with_calc(copper_bulk((3, 3, 3), 300),
                                      'asap-emt'), 30),
}


@SLOW
@pytest.mark.parametrize('case', sorted(BLOW_UPS))
def test_a_blow_up_stops_within_two_steps_of_the_tolerance(case):
    make, dt_fs = BLOW_UPS[case]
    # The checks do not change the state, so an unchecked run shows where
    # the checked one crosses the tolerance.
    dyn = ReversibleVerlet(make(), dt_fs * units.fs)
    start = snapshot(dyn.atoms)
    # Whichever detector comes first: the energy check or the range.
    with np.errstate(all='ignore'):
        with pytest.raises((UnstableIntegrationError, QuantumRangeError),
                           match='step was not taken'):
            dyn.run(600)
    limit = dyn.engine.invariant.limit
    energies, _ = energy_trace(make(), dt_fs * units.fs, dyn.nsteps + 2)
    beyond = np.flatnonzero(np.abs(energies - energies[0]) > limit)
    assert beyond.size, 'the control: the unchecked run crosses it'
    first = int(beyond[0])
    # Stopped before the step after the first one beyond the tolerance
    # (or after the second): at most two such steps committed.
    assert first <= dyn.nsteps <= first + 1
    run_back(dyn, dyn.nsteps, start)


@SLOW
def test_a_run_that_ends_unstable_between_checks_still_runs_back():
    # 100 fs on cold Ar55: a run that ends at the first step beyond the
    # tolerance has not been checked there (a check comes before a step),
    # and the way back, which starts there, must not be stopped by it.
    def cluster():
        return with_calc(argon_cluster(3, 40), 'ase-lj')

    energies, _ = energy_trace(cluster(), 100 * units.fs, 400)
    dyn = ReversibleVerlet(cluster(), 100 * units.fs)
    limit = dyn.system.energy()[1]
    first = int(np.flatnonzero(np.abs(energies - energies[0]) > limit)[0])
    start = snapshot(dyn.atoms)
    dyn.run(first)
    assert dyn.engine.invariant.limit == limit
    assert abs(dyn.atoms.get_total_energy() - energies[0]) > limit
    run_back(dyn, first, start)


# -- hot, evaporating cluster -------------------------------------------------

def nearest_neighbour_distances(x_nc):
    d = np.linalg.norm(x_nc[:, None] - x_nc[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def test_evaporating_cluster_runs_back_exactly():
    atoms = with_calc(argon_cluster(2, 2000), 'ase-lj')
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    centre = start[0].mean(axis=0)

    dyn.run(500)
    # Control: the cluster has boiled off.
    assert (nearest_neighbour_distances(atoms.positions) > AR_RC).sum() >= 3
    assert np.linalg.norm(atoms.positions - centre, axis=1).max() > 40.0
    run_back(dyn, 500, start)


# -- close contacts -----------------------------------------------------------

def pair(symbol, gap, calc):
    atoms = Atoms(symbol * 2, positions=[(0, 0, 0), (gap, 0, 0)])
    atoms.center(vacuum=10.0)
    return with_calc(atoms, calc)


def copper_contact(fraction, calc):
    """Perfect Cu bulk with atom 0 moved to ``fraction`` of a bond length
    from a neighbour."""
    atoms = bulk('Cu', cubic=True) * (3, 3, 3)
    vectors = atoms.get_distances(0, range(1, len(atoms)), mic=True,
                                  vector=True)
    nearest = vectors[np.argmin(np.linalg.norm(vectors, axis=1))]
    atoms.positions[0] += (1 - fraction) * nearest
    return with_calc(atoms, calc)


CONTACTS = {
    'Ar2-half-sigma': (lambda: pair('Ar', 0.5 * AR_SIGMA, 'ase-lj'), 1e3),
    'Cu2-hundredth-bond': (lambda: pair('Cu', 0.01 * CU_BOND, 'ase-emt'),
                           3e3),
    'Cu-bulk-asap3': (lambda: copper_contact(0.1, 'asap-emt'), 1e3),
}


@pytest.mark.parametrize('contact', list(CONTACTS))
def test_close_contact_the_step_cannot_resolve_is_stopped_reversibly(
        contact):
    make, min_force = CONTACTS[contact]
    atoms = make()
    assert np.abs(atoms.get_forces()).max() > min_force  # control
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)

    with pytest.raises(UnstableIntegrationError,
                       match='total energy has changed by .* step was not '
                             'taken'):
        dyn.run(250)
    assert 0 < dyn.nsteps <= ENERGY_CHECK_INTERVAL
    assert_atoms_show_committed_state(dyn)
    run_back(dyn, dyn.nsteps, start)


@pytest.mark.parametrize('contact', list(CONTACTS))
def test_close_contact_with_the_check_off_runs_back_exactly(contact):
    make, min_force = CONTACTS[contact]
    atoms = make()
    e0 = atoms.get_total_energy()
    dyn = ReversibleVerlet(atoms, DT, energy_check=0)
    start = snapshot(atoms)

    try:
        dyn.run(200)
    except Exception as error:
        # asap3 refuses atoms that come closer than its tables reach (how
        # close depends on the last bits of the trajectory): a loud stop,
        # after which the last committed step must still run back.
        if type(error).__name__ != 'AsapError':
            raise
        assert 'Collision' in str(error)
        assert_atoms_show_committed_state(dyn)
    # Control: the contact blew the atoms apart and the 5 fs step could
    # not follow it: the energy is not conserved (what the check catches).
    speed = np.abs(atoms.get_velocities()).max() * units.fs  # Å/fs
    assert speed > 0.1
    assert abs(atoms.get_total_energy() - e0) > 1.0
    run_back(dyn, dyn.nsteps, start)


@SLOW
def test_a_blow_up_inside_the_ranges_is_stopped_by_the_energy_check():
    # A large step on a cold cluster: the energy grows for hundreds of
    # steps before any momentum leaves the fixed-point range.
    def cluster():
        return with_calc(argon_cluster(3, 40), 'ase-lj')

    dt, steps = 100 * units.fs, 600
    dyn = ReversibleVerlet(cluster(), dt, energy_check=0)
    with pytest.raises(QuantumRangeError):
        dyn.run(steps)
    unchecked = dyn.nsteps  # control: how far the range alone lets it go

    dyn = ReversibleVerlet(cluster(), dt)
    start = snapshot(dyn.atoms)
    with pytest.raises(UnstableIntegrationError):
        dyn.run(steps)
    assert dyn.nsteps < unchecked
    assert_atoms_show_committed_state(dyn)
    run_back(dyn, dyn.nsteps, start)


@pytest.mark.parametrize('make, min_force, what, first_step', [
    (lambda: pair('Ar', 0.3 * AR_SIGMA, 'ase-lj'), 1e5,
     'momentum increment', True),
    (lambda: copper_contact(0.1, 'ase-emt'), 1e3, 'momentum', False),
], ids=['Ar2-0.3-sigma', 'Cu-bulk-ase-emt'])
def test_contact_beyond_the_momentum_range_stops_reversibly(
        make, min_force, what, first_step):
    atoms = make()
    assert np.abs(atoms.get_forces()).max() > min_force  # control
    # The range is the detector under test; the energy check would often
    # stop these runs first.
    dyn = ReversibleVerlet(atoms, DT, energy_check=0)
    start, done = run_until_refused(
        dyn, 200, QuantumRangeError,
        f'^{what} of atom [0-9]+ is outside the fixed-point range')
    assert (done == 0) == first_step
    if done == 0:
        assert_same_state(atoms, start)
    run_back(dyn, done, start)


# -- periodic diffusion -------------------------------------------------------

def argon_gas(n_atoms=4, cell_length=10.0, temperature_K=3000, seed=0):
    """Hot argon on a simple cubic lattice in a small periodic cube; ASE's
    LennardJones, whose cutoff reaches beyond half the cell."""
    k = int(np.ceil(n_atoms ** (1 / 3)))
    sites = (np.indices((k, k, k)).reshape(3, -1).T[:n_atoms] + 0.5) / k
    atoms = Atoms(f'Ar{n_atoms}', scaled_positions=sites,
                  cell=[cell_length] * 3, pbc=True)
    return with_calc(thermalize(atoms, temperature_K, seed), 'ase-lj')


@SLOW
def test_periodic_diffusion_over_cell_lengths_runs_back_exactly():
    atoms = argon_gas()
    length = atoms.cell[0, 0]
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)

    dyn.run(1000)
    # Control: unwrapped, some atom went several cell lengths.
    moved = np.linalg.norm(atoms.positions - start[0], axis=1)
    assert moved.max() > 3 * length
    run_back(dyn, 1000, start)


def test_diffusion_out_of_a_small_position_range_stops_reversibly():
    atoms = argon_gas()
    length = atoms.cell[0, 0]
    # 2**53 quanta of 2**-48 Å: positions must stay below 32 Å.
    dyn = ReversibleVerlet(atoms, DT, position_quantum=2.0**-48)
    start = snapshot(atoms)

    with pytest.raises(QuantumRangeError,
                       match='^position of atom [0-9]+ is outside the '
                             'fixed-point range'):
        dyn.run(3000)
    done = dyn.nsteps
    assert done > 0
    # Control: the atom that left wandered more than a cell from its site.
    assert np.linalg.norm(atoms.positions - start[0], axis=1).max() > length
    assert np.abs(atoms.positions).max() < 32.0
    assert_atoms_show_committed_state(dyn)
    run_back(dyn, done, start)
