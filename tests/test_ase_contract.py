"""ReversibleVerlet honours the contract of ASE's MolecularDynamics.

In the spirit of ase/test/md: the order in which ``irun`` calls the hooks,
the number of force evaluations per step, log files against trajectory
frames, the trajectory header, and drop-in use in place of VelocityVerlet.
"""

import io

import numpy as np
import pytest
from ase import units
from ase.calculators.lj import LennardJones
from ase.io import read
from ase.io.trajectory import Trajectory
from ase.md.verlet import VelocityVerlet

from ase_reversible import AnchorMovedWarning, ReversibleVerlet
from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, DT, argon_cluster, asap_lj,
                      ase_lj)
from exactness import (assert_frame_is_state, assert_frame_on_grid,
                       assert_same_state, snapshot)


class CountingLennardJones(LennardJones):
    """ASE's LennardJones, counting the calculations it actually performs."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.calculations = 0

    def calculate(self, *args, **kwargs):
        self.calculations += 1
        super().calculate(*args, **kwargs)


def counting_argon():
    atoms = argon_cluster(2, 80)
    atoms.calc = CountingLennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                      rc=AR_RC)
    return atoms


def argon(calc=asap_lj, shells=2, temperature_K=80):
    atoms = argon_cluster(shells, temperature_K)
    atoms.calc = calc()
    return atoms


class RecordingVerlet(ReversibleVerlet):
    """Notes each hook ``irun`` calls, with the step count at that moment."""

    def __init__(self, *args, **kwargs):
        self.events = []
        super().__init__(*args, **kwargs)

    def log(self):
        self.events.append(('log', self.nsteps))
        return super().log()

    def step(self):
        self.events.append(('step', self.nsteps))
        super().step()

    def observe(self):
        self.events.append(('observer', self.nsteps))


# -- irun ---------------------------------------------------------------------

def expected_irun_events(first, steps):
    """The hook sequence of ase.md.md.MolecularDynamics.irun (which also
    refreshes the forces through a private hook before each log; our loop
    does not rely on that hook, whose existence depends on the version)."""
    events = []
    if first == 0:
        events += [('log', 0), ('observer', 0)]
    for n in range(first, first + steps):
        events += [('step', n), ('log', n + 1), ('observer', n + 1)]
    return events


def test_irun_calls_hooks_in_ase_order_and_runs_continue():
    dyn = RecordingVerlet(argon(), DT)
    dyn.attach(dyn.observe)

    assert dyn.run(3) is True
    assert dyn.events == expected_irun_events(0, 3)
    assert [e for e in dyn.events if e[0] == 'observer'] == [
        ('observer', n) for n in range(4)]
    assert dyn.nsteps == 3
    assert dyn.get_time() == 3 * DT

    # A second run continues: no second initial log/observer call.
    dyn.events.clear()
    assert dyn.run(4) is True
    assert dyn.events == expected_irun_events(3, 4)
    assert sum(e[0] == 'observer' for e in dyn.events) == 4
    assert dyn.nsteps == 7
    assert dyn.get_time() == 7 * DT


def test_irun_yields_convergence_only_at_the_last_step():
    dyn = ReversibleVerlet(argon(), DT)
    assert list(dyn.irun(3)) == [False, False, False, True]
    assert list(dyn.irun(2)) == [False, False, True]
    assert dyn.nsteps == 5


def test_observer_interval_counts_from_the_first_run():
    dyn = ReversibleVerlet(argon(), DT)
    seen = []
    dyn.attach(lambda: seen.append(dyn.nsteps), interval=3)
    dyn.run(4)
    dyn.run(5)
    assert seen == [0, 3, 6, 9]


def test_a_run_nobody_watches_ends_as_one_that_is_watched():
    # run() without observers leaves the per-step checks out and shows the
    # momenta and the record only at its end: the same steps all the same.
    quiet, watched = ReversibleVerlet(argon(), DT), ReversibleVerlet(argon(), DT)
    seen = []
    watched.attach(lambda: seen.append(watched.atoms.get_momenta()))
    for steps in (7, 0, 5):
        quiet.run(steps)
        watched.run(steps)
        assert np.array_equal(quiet.state.ix_nc, watched.state.ix_nc)
        assert np.array_equal(quiet.state.ip_nc, watched.state.ip_nc)
        for dyn in (quiet, watched):
            assert np.array_equal(dyn.atoms.positions,
                                  dyn.state.ix_nc * dyn.grid.position_quantum)
            assert np.array_equal(dyn.atoms.get_momenta(),
                                  dyn.state.ip_nc * dyn.grid.momentum_quantum)
        assert quiet.atoms.info == watched.atoms.info
    assert len(seen) == 13 and np.array_equal(seen[-1],
                                              quiet.atoms.get_momenta())


def test_an_edit_between_runs_is_taken_by_a_run_nobody_watches():
    dyn = ReversibleVerlet(argon(), DT)
    dyn.run(3)
    dyn.atoms.positions[0, 0] += 0.01
    with pytest.warns(AnchorMovedWarning):
        dyn.run(2)
    assert dyn.engine.steps_since_anchor == 2


# -- force evaluations --------------------------------------------------------

def calculations(steps, make_dyn):
    """Calculations made by constructing a fresh system's dynamics and
    running it for ``steps``."""
    atoms = counting_argon()
    dyn = make_dyn(atoms)
    dyn.run(steps)
    dyn.close()
    return atoms.calc.calculations


def calculations_to_construct(make_dyn):
    """Calculations made by the constructor alone."""
    atoms = counting_argon()
    make_dyn(atoms).close()
    return atoms.calc.calculations


def cost_per_ten_steps(make_dyn):
    """Calculations of run(20) minus those of run(10): the one-time cost of
    setting up (the first force call, installing a sorted neighbour list)
    cancels, leaving the cost of ten steps."""
    return calculations(20, make_dyn) - calculations(10, make_dyn)


def output_kwargs(output, tmp_path, loginterval):
    kwargs = {'loginterval': loginterval}
    if output in ('logger', 'both'):
        kwargs['logfile'] = io.StringIO()
    if output in ('trajectory', 'both'):
        kwargs['trajectory'] = str(tmp_path / 'md.traj')
    return kwargs


@pytest.mark.parametrize('output', ['none', 'logger', 'trajectory', 'both'])
def test_velocity_scheme_costs_one_force_evaluation_per_step(tmp_path, output):
    # Kick-drift-kick ends each step holding the forces and energy at the
    # new positions, so loggers and trajectories must not trigger more.
    def make(atoms):
        return ReversibleVerlet(atoms, DT, scheme='velocity',
                                **output_kwargs(output, tmp_path, 1))

    assert cost_per_ten_steps(make) == 10
    # The one-time cost is the constructor's (this subclass of ASE's
    # LennardJones is probed), then the first call plus at most one
    # re-evaluation after the sorted neighbour list goes in.
    assert calculations(10, make) - calculations_to_construct(make) - 10 <= 2


def test_position_scheme_costs_one_force_evaluation_per_step_unlogged():
    # The energy check is off: its cost is counted on its own below.
    def make(atoms):
        return ReversibleVerlet(atoms, DT, scheme='position', energy_check=0)

    assert cost_per_ten_steps(make) == 10


@pytest.mark.parametrize('scheme, per_check', [('velocity', 0),
                                               ('position', 1)])
def test_energy_check_costs_an_evaluation_only_where_none_is_cached(
        scheme, per_check):
    # Steps 6-10 start with nsteps 5-9, of which 8 is a check step (the
    # powers of two, then every 100); steps 11-20 hold one, 16.  A cold,
    # stable cluster never moves the kinetic-energy trigger that far.
    def make(atoms):
        return ReversibleVerlet(atoms, DT, scheme=scheme)

    assert calculations(10, make) - calculations(5, make) == 5 + per_check
    assert cost_per_ten_steps(make) == 10 + per_check


@pytest.mark.parametrize('loginterval', [1, 5])
def test_position_scheme_pays_one_more_evaluation_per_logged_step(loginterval):
    # Drift-kick-drift ends a step at positions where no forces are known:
    # each log line needs its own calculation of the energy.
    def make(atoms):
        return ReversibleVerlet(atoms, DT, scheme='position', energy_check=0,
                                logfile=io.StringIO(), loginterval=loginterval)

    logged_in_steps_11_to_20 = 10 // loginterval
    assert cost_per_ten_steps(make) == 10 + logged_in_steps_11_to_20


def test_velocity_verlet_reference_costs_one_evaluation_per_step():
    def make(atoms):
        return VelocityVerlet(atoms, DT, logfile=io.StringIO())

    assert cost_per_ten_steps(make) == 10


def test_continued_and_reversed_runs_cost_one_evaluation_per_step():
    atoms = counting_argon()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(5)
    before = atoms.calc.calculations
    dyn.run(10)
    assert atoms.calc.calculations - before == 10
    # Reversing keeps the forces at the current positions: the first
    # reversed kick reuses them.
    before = atoms.calc.calculations
    dyn.reverse()
    dyn.run(10)
    assert atoms.calc.calculations - before == 10


# -- log file against trajectory frames ---------------------------------------

def log_rows(path):
    header, *lines = path.read_text().splitlines()
    assert header.split()[:2] == ['Time[ps]', 'Etot[eV]']
    return [line.split() for line in lines]


def test_log_lines_match_trajectory_frames(tmp_path):
    traj, log = tmp_path / 'md.traj', tmp_path / 'md.log'
    # ASE's calculator: asap3 results are not stored in trajectory frames.
    dyn = ReversibleVerlet(argon(ase_lj), DT, trajectory=str(traj),
                           logfile=str(log), loginterval=5)
    dyn.run(20)
    dyn.close()

    frames = read(traj, ':')
    rows = log_rows(log)
    assert len(frames) == len(rows) == 5

    for step, (frame, row) in enumerate(zip(frames, rows)):
        time_ps, etot, epot, ekin = row[:4]
        frame_epot = frame.get_potential_energy()
        frame_ekin = frame.get_kinetic_energy()
        # The logger prints 4 decimals for small systems; the frame holds
        # the very floats it formatted.
        assert f'{frame_epot + frame_ekin:.4f}' == etot
        assert f'{frame_epot:.4f}' == epot
        assert f'{frame_ekin:.4f}' == ekin
        assert f'{5 * step * DT / (1000 * units.fs):.4f}' == time_ps
        assert frame.info['reversible']['time'] == 5 * step * DT

        assert_frame_on_grid(frame, dyn.grid)

    # The last frame is the integrator's exact state, not an approximation.
    assert_frame_is_state(frames[-1], dyn)


def test_trajectory_description_names_the_integrator_and_its_grid(tmp_path):
    path = tmp_path / 'md.traj'
    dyn = ReversibleVerlet(argon(ase_lj), DT, trajectory=str(path),
                           scheme='position', loginterval=2)
    dyn.run(4)
    dyn.close()

    settings = dyn.todict()
    assert settings['md-type'] == 'ReversibleVerlet'
    assert settings['timestep'] == DT
    assert settings['scheme'] == 'position'
    assert settings['position_quantum'] == dyn.grid.position_quantum
    assert settings['momentum_quantum'] == dyn.grid.momentum_quantum
    assert settings['force_purity'] == 'sorted'

    with Trajectory(path) as traj:
        assert len(traj) == 3
        description = traj.description
    assert description['md-type'] == 'ReversibleVerlet'
    assert description['interval'] == 2
    for key in ('timestep', 'scheme', 'position_quantum', 'momentum_quantum',
                'force_purity'):
        assert description[key] == settings[key], key


def test_force_purity_in_description_follows_the_calculator():
    assert ReversibleVerlet(argon(asap_lj), DT).todict()['force_purity'] \
        == 'guarded'


@pytest.mark.parametrize('append', [True, False])
def test_append_trajectory_keeps_earlier_frames(tmp_path, append):
    path = tmp_path / 'md.traj'
    atoms = argon()
    first = ReversibleVerlet(atoms, DT, trajectory=str(path), loginterval=5)
    first.run(10)
    first.close()
    earlier = read(path, ':')
    assert len(earlier) == 3

    second = ReversibleVerlet(atoms, DT, trajectory=str(path), loginterval=5,
                              append_trajectory=append)
    second.run(10)
    second.close()
    frames = read(path, ':')

    if not append:
        assert len(frames) == 3
        return
    assert len(frames) == 6
    for old, kept in zip(earlier, frames[:3]):
        assert np.array_equal(kept.positions, old.positions)
        assert np.array_equal(kept.get_momenta(), old.get_momenta())
    # The appended run starts where the first one stopped.
    assert np.array_equal(frames[3].positions, earlier[-1].positions)
    assert frames[-1].info['reversible']['time'] == 20 * DT


# -- time and reversal --------------------------------------------------------

def test_reverse_runs_the_clock_back_to_zero():
    atoms = argon()
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(10)
    assert dyn.get_time() == dyn.nsteps * abs(dyn.dt) == 10 * DT

    assert dyn.reverse() is dyn
    assert dyn.dt == -DT
    dyn.run(4)
    assert dyn.get_time() == 6 * DT
    dyn.run(6)
    assert dyn.get_time() == 0.0
    assert dyn.nsteps == 20  # ASE's step counter keeps counting up
    assert_same_state(atoms, start)

    # Reversing twice restores the forward direction.
    dyn.reverse()
    dyn.run(3)
    assert dyn.get_time() == 3 * DT


def test_negative_timestep_runs_backwards_from_the_start():
    atoms = argon()
    dyn = ReversibleVerlet(atoms, -DT)
    start = snapshot(atoms)
    dyn.run(8)
    assert dyn.get_time() == -8 * DT
    dyn.reverse().run(8)
    assert dyn.get_time() == 0.0
    assert_same_state(atoms, start)


# -- drop-in replacement ------------------------------------------------------

def test_positional_arguments_of_velocity_verlet_work(tmp_path):
    atoms = argon(ase_lj)
    reversible = ReversibleVerlet(atoms, DT, str(tmp_path / 'rv.traj'),
                                  str(tmp_path / 'rv.log'), 4)
    # Start the reference from the snapped state the constructor left.
    reference_atoms = atoms.copy()
    reference_atoms.calc = ase_lj()
    reference = VelocityVerlet(reference_atoms, DT, str(tmp_path / 'vv.traj'),
                               str(tmp_path / 'vv.log'), 4)
    reversible.run(12)
    reference.run(12)
    reversible.close()
    reference.close()

    # What ASE keeps in .trajectory depends on its version (3.23: None, 3.29:
    # the path); the integrator keeps what VelocityVerlet keeps.
    if reference.trajectory is None:
        assert reversible.trajectory is None
    else:
        assert reversible.trajectory == tmp_path / 'rv.traj'
        assert reference.trajectory == tmp_path / 'vv.traj'
    frames = read(tmp_path / 'rv.traj', ':')
    reference_frames = read(tmp_path / 'vv.traj', ':')
    assert len(frames) == len(reference_frames) == 4
    assert len(log_rows(tmp_path / 'rv.log')) == 4
    assert len(log_rows(tmp_path / 'vv.log')) == 4

    # Same equations of motion: snapping to the grid leaves ~1e-11 here,
    # while a wrong factor in any kick or drift would be orders larger.
    for frame, ref in zip(frames, reference_frames):
        assert np.abs(frame.positions - ref.positions).max() < 1e-9
        assert np.abs(frame.get_momenta() - ref.get_momenta()).max() < 1e-9
