"""Restarts a user can predict: the dynamics that wrote a frame goes on
with its run, clock included; any other starts its own at 0, as a new
ASE dynamics does, and says nothing it need not; a thermostat frame
resumed without its buffer file, and a frame rounded by a text format,
say so once, at the user's line."""

import io
import warnings

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.io import Trajectory, read, write
from ase.md.langevin import Langevin

from ase_reversible import (AnchorMovedWarning, RetraceLimitError,
                            ReversibleLangevin, ReversibleVerlet)

from conftest import copper_bulk
from exactness import assert_same_state, snapshot

FRICTION = 0.01 / units.fs


def copper():
    """32 rattled Cu atoms at 300 K with ASE's EMT."""
    atoms = copper_bulk((2, 2, 2), 300, seed=1)
    atoms.calc = EMT()
    return atoms


def langevin(atoms, **kwargs):
    return ReversibleLangevin(atoms, 5 * units.fs, temperature_K=300,
                              friction=FRICTION, seed=7, **kwargs)


def ours(caught):
    """The warnings in ``caught`` that this package issued."""
    return [w for w in caught
            if issubclass(w.category, AnchorMovedWarning)
            or 'ase_reversible' in w.filename]


def test_another_dynamics_on_atoms_that_ran_starts_its_clock_at_0():
    atoms = copper()
    langevin(atoms).run(40)
    quanta = {key: atoms.info['reversible'][key]
              for key in ('position_quantum', 'momentum_quantum')}
    before = snapshot(atoms)
    log = io.StringIO()
    dt = 2 * units.fs
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = ReversibleVerlet(atoms, dt, logfile=log)
        dyn.run(40)
    assert ours(caught) == []
    assert dyn.get_time() == 40 * dt
    assert log.getvalue().splitlines()[1].split()[0] == '0.0000'
    assert atoms.info['reversible']['time'] == 40 * dt
    # The grid is kept: the frame is taken as it is, bit for bit.
    assert (dyn.grid.position_quantum, dyn.grid.momentum_quantum) == (
        quanta['position_quantum'], quanta['momentum_quantum'])
    dyn.reverse().run(40)
    assert_same_state(atoms, before)


def test_the_same_class_at_another_time_step_starts_its_clock_at_0():
    atoms = copper()
    ReversibleVerlet(atoms, 5 * units.fs).run(10)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = ReversibleVerlet(atoms, 2 * units.fs)
    assert ours(caught) == []
    assert dyn.get_time() == 0.0


def test_the_dynamics_that_wrote_a_frame_goes_on_with_its_clock(tmp_path):
    atoms = copper()
    dt = 5 * units.fs
    dyn = ReversibleVerlet(atoms, dt, trajectory=str(tmp_path / 'md.traj'),
                           loginterval=10)
    dyn.run(30)
    dyn.close()
    frame = read(tmp_path / 'md.traj', 2)
    frame.calc = EMT()
    resumed = ReversibleVerlet(frame, dt)
    assert resumed.get_time() == 20 * dt
    resumed.run(10)
    assert_same_state(frame, snapshot(atoms))
    assert resumed.get_time() == pytest.approx(dyn.get_time(), rel=1e-15)


def langevin_frames(tmp_path, steps=30):
    """A ReversibleLangevin run of ``steps`` steps writing every frame
    (the last is frame ``steps``), its buffer file at the end, the state
    there and the state 20 steps further on."""
    atoms = copper()
    traj, saved = tmp_path / 'md.traj', tmp_path / 'md.npz'
    dyn = langevin(atoms, trajectory=str(traj))
    dyn.run(steps)
    dyn.write_buffer(saved)
    dyn.close()
    frame = snapshot(atoms)
    dyn.run(20)
    return traj, saved, frame, snapshot(atoms)


def test_a_thermostat_frame_without_its_buffer_warns_once_at_the_users_line(
        tmp_path):
    traj, saved, at_frame, later = langevin_frames(tmp_path)
    frame = read(traj, 30)
    frame.calc = EMT()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        resumed = langevin(frame)
    assert len(ours(caught)) == 1
    warning = caught[0]
    assert warning.category is AnchorMovedWarning
    assert warning.filename == __file__
    for words in ('without the buffer file', 'write_buffer()', 'buffer=path',
                  'not bit for bit', 'the way back stops at this frame'):
        assert words in str(warning.message)
    resumed.run(20)
    assert not np.array_equal(frame.get_positions(), later[0])
    resumed.reverse().run(20)
    assert_same_state(frame, at_frame)
    with pytest.raises(RetraceLimitError):
        resumed.run(1)


def test_a_thermostat_frame_with_its_buffer_goes_on_exactly_and_quietly(
        tmp_path):
    traj, saved, at_frame, later = langevin_frames(tmp_path)
    frame = read(traj, 30)
    frame.calc = EMT()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = langevin(frame, buffer=saved)
    resumed.run(20)
    assert_same_state(frame, later)
    assert resumed.get_time() == pytest.approx(50 * 5 * units.fs, rel=1e-15)


def test_the_first_frame_of_a_thermostat_run_needs_no_buffer(tmp_path):
    """At the run's anchor the buffer is empty: the frame alone goes on
    exactly, so nothing is said."""
    traj, _, _, _ = langevin_frames(tmp_path, steps=20)
    frame = read(traj, 0)
    frame.calc = EMT()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = langevin(frame)
    resumed.run(20)
    assert_same_state(frame, snapshot(read(traj, 20)))


def test_a_thermostat_frame_taken_by_another_dynamics_is_quiet(tmp_path):
    traj, _, at_frame, _ = langevin_frames(tmp_path)
    frame = read(traj, 30)
    frame.calc = EMT()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = ReversibleVerlet(frame, 5 * units.fs)
    assert ours(caught) == []
    assert dyn.get_time() == 0.0
    assert dyn.forces_match_record is None
    assert_same_state(frame, at_frame)


def test_a_frame_rounded_by_extxyz_is_named_so_at_the_users_line(tmp_path):
    atoms = copper()
    ReversibleVerlet(atoms, 5 * units.fs).run(10)
    write(tmp_path / 'frame.extxyz', atoms)
    frame = read(tmp_path / 'frame.extxyz')
    assert frame.info['reversible'] == atoms.info['reversible']
    frame.calc = EMT()
    with pytest.warns(AnchorMovedWarning) as caught:
        dyn = ReversibleVerlet(frame, 5 * units.fs)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert 'at most 8 decimal places' in message
    assert 'rounded by a text format such as extxyz' in message
    assert 'write frames with .traj' in message
    assert 'changed since' not in message
    assert caught[0].filename == __file__
    assert dyn.get_time() == 0.0


@pytest.mark.parametrize('from_a_frame', [False, True],
                         ids=['fresh-atoms', 'a-frame-of-a-reversible-run'])
def test_atoms_equilibrated_with_ases_langevin_are_a_quiet_new_start(
        from_a_frame, tmp_path):
    """The common workflow: equilibrate with ASE's Langevin, then run
    ReversibleVerlet -- on fresh atoms, or on a frame of an earlier
    reversible run whose record the atoms still carry: a new run, its
    clock from 0, and nothing to say (ASE's dynamics start so too)."""
    atoms = copper()
    if from_a_frame:
        ReversibleVerlet(atoms, 5 * units.fs).run(10)
        with Trajectory(tmp_path / 'frame.traj', 'w') as traj:
            traj.write(atoms)
        atoms = read(tmp_path / 'frame.traj')
        atoms.calc = EMT()
        assert 'reversible' in atoms.info
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', FutureWarning)
        Langevin(atoms, 5 * units.fs, temperature_K=300, friction=FRICTION,
                 fixcm=False, rng=np.random.default_rng(0)).run(10)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        dyn = ReversibleVerlet(atoms, 5 * units.fs)
        start = snapshot(atoms)
        dyn.run(10)
    assert ours(caught) == []
    assert dyn.get_time() == 10 * 5 * units.fs
    dyn.reverse().run(10)
    assert_same_state(atoms, start)
