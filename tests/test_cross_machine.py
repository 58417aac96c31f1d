"""A run written on one machine and run back on another: back bit for bit,
or a MachineChangedWarning before the first step back.  Never a silent miss.

The other machines are emulated in subprocesses (``tests/machines.py``):
leg 1 writes a trajectory on one, leg 2 reads its last frame on another,
attaches the calculator, constructs the integrator, reverses and runs back.
The in-process tests cover the detection itself: no alarm where the forces
are equal, a warning where they differ, and what the anchor then is.
"""

import json
import warnings

import numpy as np
import pytest
from ase import units
from ase.calculators.lj import LennardJones as AseLennardJones
from ase.io import read

from ase_reversible import (AnchorMovedWarning, LennardJones,
                            MachineChangedWarning, RetraceLimitError,
                            ReversibleLangevin, ReversibleVerlet)
from ase_reversible.core.record import INFO_KEY

from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, CALCULATORS, DT,
                      argon_cluster, copper_bulk, needs_asap3)
from exactness import assert_same_state, snapshot
from machines import MACHINES, run_leg

FRICTION = 0.01 / units.fs

# -- two legs on two machines -------------------------------------------------

#: What both legs share: systems, calculators and dynamics by name.
COMMON = f'''
import json, warnings
import numpy as np
from ase import units
from ase.io import read
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase_reversible import (MachineChangedWarning, RetraceLimitError,
                            ReversibleLangevin, ReversibleVerlet)
from ase_reversible.app.systems import argon_cluster, copper_bulk

SYSTEMS = {{'Cu32': lambda: copper_bulk((2, 2, 2), 600),
            'Ar55': lambda: argon_cluster(3, 120)}}

def calculator(name):
    if name == 'ase-emt':
        return EMT()
    if name == 'ase-lj':
        return LennardJones(sigma={AR_SIGMA!r}, epsilon={AR_EPSILON!r},
                            rc={AR_RC!r})
    import asap3
    return asap3.EMT()

def dynamics(atoms, kind, **kwargs):
    if kind.startswith('verlet'):  # 'verlet' or 'verlet-position'
        return ReversibleVerlet(atoms, {DT!r}, scheme=kind[7:] or 'velocity',
                                **kwargs)
    return ReversibleLangevin(atoms, {DT!r}, 300, {FRICTION!r}, seed=7,
                              **kwargs)
'''

#: Leg 1: a run of ``steps`` written to run.traj (first and last frame),
#: the forces at the end, and a Langevin run's buffer file.
WRITE = '''
atoms = SYSTEMS[{system!r}]()
atoms.calc = calculator({calc!r})
dyn = dynamics(atoms, {kind!r}, trajectory='run.traj', loginterval={steps})
dyn.run({steps})
if {kind!r} == 'langevin':
    dyn.write_buffer('buffer.npz')
dyn.close()
np.save('forces.npy', atoms.get_forces())
'''

#: Leg 2: resume the last frame, reverse, run back ``steps``; report as
#: JSON what was warned before the first step back and where the run ended.
RUN_BACK = '''
first, frame = read('run.traj', 0), read('run.traj', -1)
frame.calc = calculator({calc!r})
extra = {{'buffer': 'buffer.npz'}} if {kind!r} == 'langevin' else {{}}
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    dyn = dynamics(frame, {kind!r}, **extra)
    # The forces the integrator computed at the frame, against leg 1's.
    forces_equal = bool(np.array_equal(frame.get_forces(),
                                       np.load('forces.npy')))
    warned = [str(w.message) for w in caught
              if issubclass(w.category, MachineChangedWarning)]
    dyn.reverse()
    stopped = None
    try:
        dyn.run({steps})
    except RetraceLimitError as error:
        stopped = str(error)
back = bool(np.array_equal(frame.positions, first.positions)
            and np.array_equal(frame.get_momenta(), first.get_momenta()))
print(json.dumps({{'warned': warned, 'forces_equal': forces_equal,
                  'back': back, 'stopped': stopped,
                  'match': dyn.forces_match_record}}))
'''


def cross(tmp_path, calc, system, steps, there, here, kind='verlet'):
    """Leg 1 on machine ``there``, leg 2 on ``here``; leg 2's report."""
    settings = dict(calc=calc, system=system, steps=steps, kind=kind)
    run_leg(there, COMMON + WRITE.format(**settings), tmp_path)
    out = run_leg(here, COMMON + RUN_BACK.format(**settings), tmp_path)
    return json.loads(out.strip().splitlines()[-1])


def assert_no_silent_miss(out):
    """Back bit for bit with no warning, or warned before the first step
    back (leg 2 reads the warnings before it reverses)."""
    if out['back']:
        assert not out['warned'] or out['forces_equal'] is False
        return
    assert out['warned'], f'the run back missed the start silently: {out}'


def sse4_changes_numpy_dispatch():
    """Whether 'sse4' switches off a SIMD target numpy uses here (then
    np.exp and powers give other bits: tests/machines.py)."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:
        from numpy.core import _multiarray_umath as umath
    on = {f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f)}
    return bool(on & set(MACHINES['sse4'][0]))


def test_ase_emt_run_back_on_another_machine_warns_or_returns(tmp_path):
    out = cross(tmp_path, 'ase-emt', 'Cu32', 10, 'native', 'sse4')
    assert_no_silent_miss(out)
    # The digest saw what the forces show: no false alarm, no blind spot.
    assert bool(out['warned']) == (not out['forces_equal'])
    assert out['match'] is (not out['warned'])
    if sse4_changes_numpy_dispatch():
        # np.exp changes bits here, so the detection was exercised.
        assert out['warned'] and 'differ' in out['warned'][0]


@pytest.mark.slow
@pytest.mark.parametrize('calc, system, steps', [('ase-emt', 'Cu32', 30),
                                                 ('ase-lj', 'Ar55', 30)])
def test_same_machine_control_is_exact_and_quiet(calc, system, steps,
                                                 tmp_path):
    out = cross(tmp_path, calc, system, steps, 'native', 'native')
    assert out['back'] and not out['warned'] and out['forces_equal']
    assert out['match'] is True


@pytest.mark.slow
@pytest.mark.parametrize('here', ['avx2', 'sse4'])
@pytest.mark.parametrize('calc, system, steps', [('ase-emt', 'Cu32', 30),
                                                 ('ase-lj', 'Ar55', 30)])
def test_ase_calculators_on_another_machine(calc, system, steps, here,
                                            tmp_path):
    out = cross(tmp_path, calc, system, steps, 'native', here)
    assert_no_silent_miss(out)
    assert bool(out['warned']) == (not out['forces_equal'])


@pytest.mark.slow
def test_drift_kick_drift_on_another_machine(tmp_path):
    out = cross(tmp_path, 'ase-emt', 'Cu32', 30, 'native', 'sse4',
                kind='verlet-position')
    assert_no_silent_miss(out)
    # (The digest is of the last kick's forces, one drift back: leg 2's
    # forces at the frame itself are no measure of it.)
    if sse4_changes_numpy_dispatch():
        assert out['warned'] and out['match'] is False


@pytest.mark.slow
def test_asap3_emt_on_another_machine(tmp_path):
    needs_asap3()
    out = cross(tmp_path, 'asap-emt', 'Cu32', 30, 'native', 'sse4')
    assert_no_silent_miss(out)
    # Compiled C++ with no numpy dispatch: measured to come back.
    assert out['back'] and out['match'] is True


@pytest.mark.slow
def test_langevin_with_buffer_on_another_machine(tmp_path):
    out = cross(tmp_path, 'ase-emt', 'Cu32', 10, 'native', 'sse4',
                kind='langevin')
    if out['back']:
        assert not out['warned']
        return
    # Warned, and the way back past the frame refused, not missed.
    assert out['warned'] and 'RetraceLimitError' in out['warned'][0]
    assert out['stopped'] is not None


@pytest.mark.slow
def test_langevin_with_buffer_same_machine_control(tmp_path):
    out = cross(tmp_path, 'ase-emt', 'Cu32', 10, 'native', 'native',
                kind='langevin')
    assert out['back'] and not out['warned'] and out['stopped'] is None
    assert out['match'] is True


# -- the detection, in one process --------------------------------------------

def ase_lj(epsilon=AR_EPSILON):
    return AseLennardJones(sigma=AR_SIGMA, epsilon=epsilon, rc=AR_RC)


def own_lj():
    return LennardJones(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)


def written(tmp_path, build, calc, steps, **kwargs):
    """A run of ``steps`` written to a trajectory; (first frame, last)."""
    traj = tmp_path / 'run.traj'
    atoms = build()
    atoms.calc = calc()
    dyn = ReversibleVerlet(atoms, DT, trajectory=str(traj),
                           loginterval=steps, **kwargs)
    dyn.run(steps)
    dyn.close()
    return read(traj, 0), read(traj, -1)


@pytest.mark.parametrize('build, calc', [
    (lambda: copper_bulk((2, 2, 2), 600), CALCULATORS['ase-emt']),
    (lambda: argon_cluster(2, 120), own_lj)], ids=['ase-emt', 'own-lj'])
def test_equal_forces_raise_no_alarm(build, calc, tmp_path):
    first, frame = written(tmp_path, build, calc, 10)
    section = frame.info[INFO_KEY]['machine']
    assert set(section) == {'platform', 'forces', 'positions'}
    assert len(json.dumps(section)) < 600  # small, in every frame
    frame.calc = calc()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn = ReversibleVerlet(frame, DT)
    assert dyn.forces_match_record is True
    dyn.reverse().run(10)
    assert_same_state(frame, snapshot(first))


def test_other_forces_at_the_frame_warn_before_the_first_step(tmp_path):
    first, frame = written(tmp_path, lambda: argon_cluster(2, 120), ase_lj,
                           10)
    state = snapshot(frame)
    # Other forces at the frame: here other settings, elsewhere another
    # CPU's np.power.
    frame.calc = ase_lj(AR_EPSILON * (1 + 1e-9))
    with pytest.warns(MachineChangedWarning,
                      match='platforms look alike') as caught:
        dyn = ReversibleVerlet(frame, DT)
    message = str(caught[0].message)
    assert 'Written on:' in message and 'LennardJones (ase' in message
    assert dyn.forces_match_record is False
    # The frame is the anchor: the run from it is exact both ways.
    assert np.array_equal(dyn.anchor.ix_nc, dyn.state.ix_nc)
    assert_same_state(frame, state)
    dyn.run(10)
    dyn.reverse().run(10)
    assert_same_state(frame, state)
    # ... and running back past it misses, as the warning said.
    dyn.run(10)
    assert not np.array_equal(frame.positions, first.positions)


def langevin_frame_and_buffer(tmp_path):
    """Ar13 under ReversibleLangevin for 10 steps with ASE's Lennard-Jones:
    its state at the start, its last frame and its buffer file."""
    traj, saved = tmp_path / 'run.traj', tmp_path / 'buffer.npz'
    atoms = argon_cluster(2, 120)
    atoms.calc = ase_lj()
    dyn = ReversibleLangevin(atoms, DT, 300, FRICTION, seed=3,
                             trajectory=str(traj), loginterval=10)
    start = snapshot(atoms)
    dyn.run(10)
    dyn.write_buffer(saved)
    dyn.close()
    return start, read(traj, -1), saved


def test_langevin_buffer_with_other_forces_stops_at_the_frame(tmp_path):
    _, frame, saved = langevin_frame_and_buffer(tmp_path)
    state = snapshot(frame)
    frame.calc = ase_lj(AR_EPSILON * (1 + 1e-9))
    with pytest.warns(MachineChangedWarning, match='RetraceLimitError'):
        resumed = ReversibleLangevin(frame, DT, 300, FRICTION, buffer=saved)
    assert resumed.forces_match_record is False
    # The frame is now the anchor: the buffer's way back was dropped.
    assert np.array_equal(resumed.anchor.ix_nc, resumed.state.ix_nc)
    assert np.array_equal(resumed.anchor.ip_nc, resumed.state.ip_nc)
    resumed.reverse()
    with pytest.raises(RetraceLimitError):
        resumed.run(1)
    assert_same_state(frame, state)  # refused, nothing lost


def test_langevin_buffer_with_the_same_forces_goes_back(tmp_path):
    start, frame, saved = langevin_frame_and_buffer(tmp_path)
    # The file carries the section too, for a frame whose record lost it.
    with np.load(saved) as f:
        assert 'forces' in json.loads(str(f['machine']))
    del frame.info[INFO_KEY]['machine']
    frame.calc = ase_lj()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = ReversibleLangevin(frame, DT, 300, FRICTION, buffer=saved)
    assert resumed.forces_match_record is True
    resumed.reverse().run(10)
    assert_same_state(frame, start)


def test_guarded_rounding_digests_the_rounded_kick(tmp_path):
    calc = CALCULATORS['asap-emt']
    needs_asap3()
    first, frame = written(tmp_path, lambda: copper_bulk((2, 2, 2), 600),
                           calc, 10)
    section = frame.info[INFO_KEY]['machine']
    assert set(section) == {'platform', 'kick', 'kick_scale', 'positions'}
    frame.calc = calc()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn = ReversibleVerlet(frame, DT)
    assert dyn.force_purity.mode == 'guarded'
    assert dyn.forces_match_record is True
    dyn.reverse().run(10)
    assert_same_state(frame, snapshot(first))


def test_drift_kick_drift_compares_where_the_last_kick_was(tmp_path):
    # The step ends with a drift: the record digests the forces of the
    # last kick, one drift back, and says how long that drift was.
    first, frame = written(tmp_path, lambda: copper_bulk((2, 2, 2), 600),
                           CALCULATORS['ase-emt'], 10, scheme='position')
    section = frame.info[INFO_KEY]['machine']
    assert set(section) == {'platform', 'forces', 'drift', 'positions'}
    state = snapshot(frame)
    frame.calc = CALCULATORS['ase-emt']()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn = ReversibleVerlet(frame, DT, scheme='position')
    assert dyn.forces_match_record is True
    assert_same_state(frame, state)  # the drift back and forth is exact
    assert set(frame.info[INFO_KEY]['machine']) == set(section)
    dyn.reverse().run(10)
    assert_same_state(frame, snapshot(first))
    other = read(tmp_path / 'run.traj', -1)
    other.calc = ase_lj()  # another calculator: other forces
    with pytest.warns(MachineChangedWarning, match='differ'):
        ReversibleVerlet(other, DT, scheme='position', force_purity='trust')


def test_a_record_without_digest_warns_only_for_another_platform():
    # The constructor writes a record before any force call: no digest.
    atoms = argon_cluster(2, 120)
    atoms.calc = ase_lj()
    ReversibleVerlet(atoms, DT)
    section = atoms.info[INFO_KEY]['machine']
    assert set(section) == {'platform'}
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        dyn = ReversibleVerlet(atoms, DT)
    assert dyn.forces_match_record is None
    # The same frame as another machine's numpy would have written it.
    atoms.info[INFO_KEY]['machine']['platform']['simd'] = 'X86_V2'
    with pytest.warns(MachineChangedWarning, match='no digest'):
        dyn = ReversibleVerlet(atoms, DT)
    assert dyn.forces_match_record is None


def test_a_record_left_on_moved_atoms_is_not_compared(tmp_path):
    # As in an optimisation loop: the atoms are put back on the grid at
    # the start after a run; the record in atoms.info is from the end.
    atoms = argon_cluster(2, 120)
    atoms.calc = ase_lj()
    dyn = ReversibleVerlet(atoms, DT)
    start = atoms.get_positions()
    dyn.run(10)
    assert 'forces' in atoms.info[INFO_KEY]['machine']
    atoms.positions = start
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        again = ReversibleVerlet(atoms, DT)
    assert again.forces_match_record is None
    # Nor when the record says another machine wrote it.
    again.run(10)
    record = atoms.info[INFO_KEY]
    section = record['machine']
    section['platform']['simd'] = 'X86_V2'
    atoms.positions = start
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        ReversibleVerlet(atoms, DT)


def test_nose_resume_compares_too(tmp_path):
    from ase.md.velocitydistribution import Stationary
    from ase_reversible import ReversibleNose
    traj = tmp_path / 'run.traj'
    atoms = argon_cluster(2, 80)
    Stationary(atoms)
    atoms.calc = ase_lj()
    dyn = ReversibleNose(atoms, DT, 80, 100 * units.fs, trajectory=str(traj),
                         loginterval=10)
    start = snapshot(atoms)
    dyn.run(10)
    dyn.close()
    frame = read(traj, -1)
    frame.calc = ase_lj()
    with warnings.catch_warnings():
        warnings.simplefilter('error', AnchorMovedWarning)
        resumed = ReversibleNose(frame, DT, 80, 100 * units.fs)
    assert resumed.forces_match_record is True
    resumed.reverse().run(10)
    assert_same_state(frame, start)
    other = read(traj, -1)
    other.calc = ase_lj(AR_EPSILON * (1 + 1e-9))
    with pytest.warns(MachineChangedWarning):
        resumed = ReversibleNose(other, DT, 80, 100 * units.fs)
    assert resumed.forces_match_record is False


def test_platforms_differ_by_what_decides_the_bits():
    from ase_reversible.md.machine import differences, platform
    here = platform(CALCULATORS['ase-emt']())
    assert differences(here, here) == []
    # Another OpenBLAS kernel, or numpy without its AVX-512 loops: differ.
    libraries = here.get('libraries', '')
    if libraries:
        api, version = libraries.split('; ')[0].split()[:2]
        there = {**here, 'libraries': f'{api} {version} Prescott 1 threads'}
        assert differences(there, here) == ['BLAS/OpenMP']
    assert differences({**here, 'simd': 'X86_V2'}, here) == [
        "numpy's SIMD targets"]
    # A library only one process had loaded when it wrote its first record
    # (SciPy's OpenBLAS, say) is no difference of the machine.
    extra = '; '.join([libraries, 'openblas 9.9.9 Haswell 2 threads'])
    assert differences({**here, 'libraries': extra}, here) == []
