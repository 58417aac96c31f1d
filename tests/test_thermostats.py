"""What ReversibleLangevin and ReversibleBussi share: the anchor and the
way back, the seed, changed settings, ASE's trajectory and log, and
restarts from a frame with or without its buffer file.

Each test runs for both thermostats; every reversal case compares
positions and momenta with np.array_equal and checks that the
information buffer is empty again.
"""

import numpy as np
import pytest
from ase import units
from ase.io import Trajectory, read

from ase_reversible import AnchorMovedWarning, RetraceLimitError

from conftest import CALCULATORS, argon_cluster
from exactness import assert_same_state, forward_and_back, run_back, snapshot
from thermostats import (FRICTION, TAUT, THERMOSTATS, ar13,
                         assert_buffers_empty, resume, thermostat)

NAMES = list(THERMOSTATS)


def started(name, steps):
    """Ar13 under the thermostat ``name``, ``steps`` steps on from its
    start: (atoms, the dynamics, the start's positions and momenta)."""
    atoms = ar13()
    dyn = thermostat(name, atoms)
    start = snapshot(atoms)
    dyn.run(steps)
    return atoms, dyn, start


@pytest.mark.parametrize('name', NAMES)
def test_going_back_past_the_anchor_is_refused_at_a_valid_state(name):
    atoms, dyn, start = started(name, 30)
    dyn.reverse().run(30)
    with pytest.raises(RetraceLimitError, match='run forward'):
        dyn.run(1)
    assert_same_state(atoms, start)
    assert_buffers_empty(dyn)
    dyn.reverse().run(30)  # still a valid state to go on from
    assert not np.array_equal(atoms.positions, start[0])


@pytest.mark.parametrize('name', NAMES)
def test_back_and_forth_is_one_trajectory(name):
    """The noise is keyed by the step's index: retracing part of a run and
    running it again gives the same states, bit for bit."""
    straight = ar13()
    thermostat(name, straight).run(120)
    wandering = ar13()
    dyn = thermostat(name, wandering)
    dyn.run(80)
    dyn.reverse().run(50)
    dyn.reverse().run(90)
    assert_same_state(wandering, snapshot(straight))


@pytest.mark.parametrize('name, steps', [('langevin', 50), ('bussi', 40)])
def test_the_seed_decides_the_run(name, steps):
    runs = {}
    for seed in (3, 3, 4):
        atoms = ar13()
        dyn = thermostat(name, atoms, seed=seed)
        assert dyn.seed == seed
        dyn.run(steps)
        runs.setdefault(seed, []).append(snapshot(atoms))
    first, second = runs[3]
    assert np.array_equal(first[0], second[0])
    assert np.array_equal(first[1], second[1])
    assert not np.array_equal(first[1], runs[4][0][1])


@pytest.mark.parametrize('name, steps', [('langevin', 40), ('bussi', 30)])
def test_a_new_temperature_moves_the_anchor_and_reversal_leads_there(
        name, steps):
    atoms = ar13()
    dyn = thermostat(name, atoms)
    dyn.run(steps)
    with pytest.warns(AnchorMovedWarning, match='temperature'):
        dyn.set_temperature(500)
    here = snapshot(atoms)
    dyn.run(steps)
    run_back(dyn, steps, here)
    with pytest.raises(RetraceLimitError):
        dyn.run(1)


@pytest.mark.parametrize('name', NAMES)
def test_a_changed_time_step_can_be_retraced_after_setting_it_back(name):
    atoms, dyn, start = started(name, 30)
    with pytest.warns(AnchorMovedWarning):
        dyn.dt = 3 * units.fs
    dyn.run(20)
    dyn.reverse().run(20)
    with pytest.raises(RetraceLimitError):
        dyn.run(1)  # the 3 fs steps are undone; the 5 fs ones need 5 fs
    dyn.dt = -5 * units.fs  # back where the step changed: nothing to warn
    dyn.run(30)
    assert_same_state(atoms, start)


@pytest.mark.parametrize('name', NAMES)
def test_energy_minus_heat_is_conserved(name):
    atoms = argon_cluster(3, 40)
    atoms.calc = CALCULATORS['ase-lj']()
    if name == 'langevin':
        # Its noise carries no net momentum: none to start with either.
        atoms.set_momenta(atoms.get_momenta()
                          - atoms.get_momenta().mean(axis=0))
    e0 = atoms.get_total_energy()
    coupling = {'langevin': {}, 'bussi': {'taut': 50 * units.fs}}[name]
    dyn = thermostat(name, atoms, temperature_K=120, **coupling)
    dyn.run(200)
    heat = dyn.heat
    drift = atoms.get_total_energy() - heat - e0
    assert heat > 0.1  # the thermostat heated the cluster
    assert abs(drift) < 1e-3 * heat
    if name == 'langevin':
        p_thermal = np.sqrt(len(atoms) * atoms.get_masses()[0] * units.kB
                            * 120)
        assert np.abs(atoms.get_momenta().sum(axis=0)).max() \
            < 1e-8 * p_thermal


@pytest.mark.parametrize('name, key, value', [
    ('langevin', 'temperature_K', 300), ('bussi', 'taut', TAUT)])
def test_trajectory_frames_and_the_log_work_as_for_ase(name, key, value,
                                                       tmp_path):
    atoms = ar13()
    log, traj = tmp_path / 'md.log', tmp_path / 'md.traj'
    dyn = thermostat(name, atoms, trajectory=str(traj), logfile=str(log),
                     loginterval=10)
    dyn.run(50)
    dyn.close()
    frames = read(str(traj), ':')
    assert len(frames) == 6
    assert np.array_equal(frames[-1].positions, atoms.positions)
    assert len(log.read_text().splitlines()) == 7
    with Trajectory(str(traj)) as t:
        assert t.description[key] == value


# -- restarts -----------------------------------------------------------------

@pytest.mark.parametrize('name, temperature_K', [('langevin', 60),
                                                 ('bussi', 5)])
def test_a_frame_and_its_buffer_continue_bit_for_bit_and_run_back_through(
        name, temperature_K, tmp_path):
    traj, saved = tmp_path / 'md.traj', tmp_path / 'md.npz'
    atoms = ar13(temperature_K)
    dyn = thermostat(name, atoms, seed=9, trajectory=str(traj))
    start = dyn.state
    dyn.run(60)
    if name == 'bussi':  # it heats: the saved buffer holds reserve words
        assert dyn.rescale_step.buffer_for(dyn.dt).top_k.min() < 0
    dyn.write_buffer(saved)
    dyn.run(40)
    straight = dyn.state
    dyn.close()

    frame = read(str(traj), 60)
    frame.calc = CALCULATORS['ase-lj']()
    resumed = resume(name, frame, buffer=saved)
    assert resumed.seed == 9 and resumed.step_index == 60
    assert resumed.get_time() == pytest.approx(60 * 5 * units.fs)
    resumed.run(40)
    assert np.array_equal(resumed.state.ix_nc, straight.ix_nc)
    assert np.array_equal(resumed.state.ip_nc, straight.ip_nc)
    resumed.reverse().run(100)
    assert np.array_equal(resumed.state.ix_nc, start.ix_nc)
    assert np.array_equal(resumed.state.ip_nc, start.ip_nc)
    assert_buffers_empty(resumed)
    with pytest.raises(RetraceLimitError):
        resumed.run(1)


@pytest.mark.parametrize('name', NAMES)
def test_a_frame_alone_resumes_the_draws_but_not_the_way_back(name,
                                                              tmp_path):
    traj = tmp_path / 'md.traj'
    atoms = ar13()
    dyn = thermostat(name, atoms, seed=4, trajectory=str(traj))
    dyn.run(30)
    dyn.close()
    frame = read(str(traj), -1)
    frame.calc = CALCULATORS['ase-lj']()
    here = snapshot(frame)
    with pytest.warns(AnchorMovedWarning, match='without the buffer file'):
        resumed = resume(name, frame)
    assert resumed.seed == 4 and resumed.step_index == 30
    forward_and_back(resumed, 20)
    assert_same_state(frame, here)
    with pytest.raises(RetraceLimitError):
        resumed.run(1)


#: (frame, what the resumed run is given, what the refusal says).  The
#: way back past the frame would draw its noise at another temperature or
#: friction: refused, not retraced elsewhere.
REFUSED = {'langevin': [(10, {}, 'step 20 of another'),
                        (20, {'friction': 2 * FRICTION}, 'friction='),
                        (20, {'temperature_K': 350},
                         'temperature_K=300.0, not 350.0')],
           'bussi': [(10, {}, 'step 20 of another')]}


@pytest.mark.parametrize('name', NAMES)
def test_a_buffer_file_from_another_state_is_refused(name, tmp_path):
    traj, saved = tmp_path / 'md.traj', tmp_path / 'md.npz'
    atoms = ar13()
    dyn = thermostat(name, atoms, trajectory=str(traj))
    dyn.run(20)
    dyn.write_buffer(saved)
    dyn.close()
    for index, kwargs, match in REFUSED[name]:
        frame = read(str(traj), index)
        frame.calc = CALCULATORS['ase-lj']()
        with pytest.raises(ValueError, match=match):
            resume(name, frame, buffer=saved, **kwargs)
