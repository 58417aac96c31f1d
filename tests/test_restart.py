"""Exact restarts from trajectory frames, the way ASE users resume."""

import warnings

import numpy as np
import pytest
from ase.io import read

from ase_reversible import AnchorMovedWarning, ReversibleVerlet

from conftest import CALCULATORS, DT, argon_cluster, copper_bulk
from exactness import (assert_frame_is_state, assert_frame_on_grid,
                       assert_same_state, forward_and_back, snapshot)

CASES = {
    'Ar55 ase-lj': (lambda: argon_cluster(3, 120), 'ase-lj', 60, 10),
    'Ar55 asap-lj': (lambda: argon_cluster(3, 120), 'asap-lj', 600, 100),
    'Cu108 asap-emt': (lambda: copper_bulk((3, 3, 3), 600), 'asap-emt', 600,
                       100),
}


@pytest.mark.parametrize('scheme', ['velocity', 'position'])
@pytest.mark.parametrize('case', list(CASES))
def test_resume_from_a_frame_continues_bit_for_bit(case, scheme, tmp_path):
    build, calc, steps, interval = CASES[case]
    traj = tmp_path / 'md.traj'
    atoms = build()
    atoms.calc = CALCULATORS[calc]()
    dyn = ReversibleVerlet(atoms, DT, trajectory=str(traj),
                           loginterval=interval, scheme=scheme)
    start = snapshot(atoms)
    dyn.run(steps)
    end = snapshot(atoms)

    # Resume from a frame in the middle: read, attach, construct.
    frame = 2
    resumed = read(traj, frame)
    resumed.calc = CALCULATORS[calc]()
    dyn2 = ReversibleVerlet(resumed, DT, scheme=scheme)
    assert dyn2.grid == dyn.grid
    assert dyn2.get_time() == pytest.approx(frame * interval * DT)
    dyn2.run(steps - frame * interval)
    assert_same_state(resumed, end)

    # The resumed run reverses through the restart point to the start.
    dyn2.reverse()
    dyn2.run(steps)
    assert_same_state(resumed, start)
    assert dyn2.get_time() == pytest.approx(0.0, abs=1e-9)


def test_every_frame_is_on_the_grid(tmp_path):
    atoms = argon_cluster(3, 120)
    atoms.calc = CALCULATORS['asap-lj']()
    traj = tmp_path / 'md.traj'
    dyn = ReversibleVerlet(atoms, DT, trajectory=str(traj), loginterval=50)
    dyn.run(200)
    frames = read(traj, ':')
    assert len(frames) == 5
    for frame in frames:
        assert_frame_on_grid(frame, dyn.grid)
    assert_frame_is_state(frames[-1], dyn)


def test_an_edit_between_runs_is_taken_and_reversal_anchors_there():
    atoms = argon_cluster(3, 120)
    atoms.calc = CALCULATORS['asap-lj']()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(100)
    atoms.set_momenta(atoms.get_momenta() * 1.1)
    with pytest.warns(AnchorMovedWarning, match='reversal now leads back'):
        dyn.run(1)
    dyn.reverse()
    dyn.run(1)
    edited = snapshot(atoms)
    # The edit was snapped to the grid and is a new anchor.
    ip = edited[1] / dyn.grid.momentum_quantum
    assert np.array_equal(ip, np.rint(ip))
    dyn.reverse()
    dyn.run(300)
    dyn.reverse()
    dyn.run(300)
    assert_same_state(atoms, edited)


def frame_of_a_run(tmp_path, steps, index):
    """Frame ``index`` of an Ar13 run of ``steps`` steps, calculator attached."""
    traj = tmp_path / 'md.traj'
    atoms = argon_cluster(2, 60)
    atoms.calc = CALCULATORS['ase-lj']()
    ReversibleVerlet(atoms, DT, trajectory=str(traj), loginterval=10).run(steps)
    frame = read(traj, index)
    frame.calc = CALCULATORS['ase-lj']()
    return frame


def test_a_frame_edited_after_it_was_written_starts_a_new_run(tmp_path):
    """Re-thermalising a frame makes it a new start, not a restart."""
    from ase.md.langevin import Langevin
    frame = frame_of_a_run(tmp_path, 40, 3)
    Langevin(frame, DT, temperature_K=60, friction=0.01, fixcm=False,
             rng=np.random.default_rng(0)).run(5)
    with warnings.catch_warnings():
        # A new start the user made: nothing to say.
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn = ReversibleVerlet(frame, DT)
    assert dyn.get_time() == 0.0
    # Still exactly reversible from the new start.
    start, moved = forward_and_back(dyn, 30)
    assert moved
    assert_same_state(frame, start)


def test_a_frame_with_new_velocities_starts_a_new_run(tmp_path):
    frame = frame_of_a_run(tmp_path, 20, -1)
    frame.set_momenta(frame.get_momenta() * 1.01)
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        assert ReversibleVerlet(frame, DT).get_time() == 0.0


@pytest.mark.parametrize('writer, reader', [('ReversibleBussi',
                                             'ReversibleLangevin'),
                                            ('ReversibleLangevin',
                                             'ReversibleBussi')])
def test_a_buffer_file_of_another_dynamics_is_refused_by_name(
        writer, reader, tmp_path):
    import ase_reversible
    from ase import units
    settings = {'ReversibleBussi': (300, 100 * units.fs),
                'ReversibleLangevin': (300, 0.02 / units.fs)}
    traj, saved = tmp_path / 'md.traj', tmp_path / 'md.npz'
    atoms = argon_cluster(2, 60)
    atoms.calc = CALCULATORS['ase-lj']()
    dyn = getattr(ase_reversible, writer)(atoms, 5 * units.fs,
                                          *settings[writer], seed=3,
                                          trajectory=str(traj))
    dyn.run(10)
    dyn.write_buffer(saved)
    dyn.close()
    frame = read(str(traj), -1)
    frame.calc = CALCULATORS['ase-lj']()
    with pytest.raises(ValueError, match=f'written by {writer}'):
        getattr(ase_reversible, reader)(frame, 5 * units.fs,
                                        *settings[reader], seed=3,
                                        buffer=saved)
