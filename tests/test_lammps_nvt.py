"""Exact reversible Nosé dynamics inside LAMMPS (fix reversible/nvt), on one
and on two MPI ranks.

Every job runs tests/lammps_nvt_worker.py: on two ranks under ``mpiexec``,
on one in the test's process (tests/lammps_here.py); its rank 0 saves the
gathered states, compared here with ``np.array_equal``: unwrapped
positions, real velocities, the virtual velocities ``v'`` (recovered from
them and ``s``, and checked to show them again), and ``s``, ``pi`` and the
real-time clock.
"""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import needs_compiler
from lammps_here import run_here
from lammps_systems import fcc_box
from test_lammps import launch
from tiers import SLOW

WORKER = Path(__file__).with_name('lammps_nvt_worker.py')
PARTS = ('ids', 'x', 'v', 'vv', 'thermostat')


@pytest.fixture(autouse=True)
def _compiler():
    # Every test here builds or loads the plugin, or tests what the
    # compiled step refuses.
    needs_compiler()


def job(ranks, name, tmp_path, **options):
    out = tmp_path / f'{name}-{ranks}.npz'
    args = [WORKER, name, out,
            *[f'{key}={value}' for key, value in options.items()]]
    if ranks == 1:
        run_here(*args)
    else:
        done = launch(ranks, *args)
        assert done.returncode == 0, done.stderr[-3000:]
    with np.load(out) as saved:
        result = {key: saved[key] for key in saved.files}
    result['counters'] = json.loads(str(result['counters']))
    return result


def assert_same_state(result, a, b, other=None):
    other = other or result
    for part in PARTS:
        assert np.array_equal(result[f'{a}_{part}'], other[f'{b}_{part}']), \
            part
    # v' recovered from (v, s) shows v again, bit for bit.
    assert np.array_equal(result[f'{a}_shown'], result[f'{a}_v'])


def by_start(result, name):
    """Rows of every per-atom array in the order of the start positions:
    atom IDs from create_atoms depend on the number of ranks."""
    order = np.lexsort(result['start_x'].T)
    return {part: (result[f'{name}_{part}'] if part == 'thermostat'
                   else result[f'{name}_{part}'][order])
            for part in PARTS if part != 'ids'}


@SLOW  # the quick tier is at its bound; test_lammps_ranks has more ranks
def test_out_and_back_bit_for_bit_and_the_same_bits_on_1_and_2_ranks(
        tmp_path):
    # Two masses (two per-type sums of squared counts), 200 steps of
    # 2^-8 tau out, heating towards T* = 1.5, and 200 back.
    results = {ranks: job(ranks, 'reversal', tmp_path, system='lj-binary',
                          steps=200) for ranks in (1, 2)}
    for ranks, result in results.items():
        assert result['counters']['ranks'] == ranks
        s, pi, clock = result['out_thermostat']
        assert s != 1.0 and pi != 0.0 and clock > 0.0
        assert np.abs(result['out_x'] - result['start_x']).max() > 0.1
        assert_same_state(result, 'out', 'out')  # v' shows v
        assert_same_state(result, 'back', 'start')
        off, largest, thermostat = result['counters']['anchor']
        assert (off, largest, thermostat) == (0, 0.0, True)
    one, two = (by_start(results[r], 'out') for r in (1, 2))
    for part in one:
        assert np.array_equal(one[part], two[part]), part


@SLOW  # two jobs: the quick tier is at its bound
def test_guarded_kicks_are_recomputed_and_take_the_same_bits_on_1_and_2_ranks(
        tmp_path):
    # A fine grid and a coarse noise bound flag a quarter of the steps: the
    # compiled fix recomputes their kicks on their own ranks, the integer
    # sum of squares follows the recomputed kicks, and the thermostat's
    # s, pi and clock come out the same bits on 1 and 2 ranks.
    results = {ranks: job(ranks, 'reversal', tmp_path, system='argon',
                          steps=60, velocity_quantum=2.0**-28,
                          force_noise=2.0**-40) for ranks in (1, 2)}
    for result in results.values():
        assert result['counters']['clean_recomputations'] >= 4
        assert_same_state(result, 'back', 'start')
    one, two = (by_start(results[r], 'out') for r in (1, 2))
    for part in one:
        assert np.array_equal(one[part], two[part]), part


@pytest.mark.parametrize('ranks, early_init', [
    (1, 0), pytest.param(2, 1, marks=SLOW)])
def test_a_restart_file_continues_bit_for_bit(ranks, early_init, tmp_path):
    # 100 steps, write_restart, 100 more on one LAMMPS instance; a new
    # instance reads the file (s, pi and the clock from it, v' from v and
    # s), runs the same 100 steps to the same bits, then 200 back to the
    # start.
    # early_init: the state is taken right after read_restart (as the
    # script runner does) and a run 0 comes before the integrator.
    steps = 100
    written = job(ranks, 'restart-write', tmp_path, system='lj-binary',
                  steps=steps, files=tmp_path)
    read = job(ranks, 'restart-read', tmp_path, system='lj-binary',
               steps=steps, files=tmp_path, early_init=early_init)
    assert read['counters']['restored']
    assert read['counters'].get('taken', True)
    assert written['half_thermostat'][0] != 1.0
    assert_same_state(read, 'half', 'half', written)
    assert_same_state(read, 'end', 'end', written)
    assert_same_state(read, 'start', 'start', written)


def test_s_reaching_zero_stops_the_run_with_the_state_valid(tmp_path):
    # T* = 50 for atoms at 1.5 with tdamp 0.01: pi falls so fast that s
    # would cross zero within a few steps.
    result = job(1, 'unstable', tmp_path, system='lj', steps=200,
                 temperature=50.0, tdamp=0.01)
    counters = result['counters']
    assert counters['refused'].startswith('UnstableIntegrationError')
    assert 'larger tdamp' in counters['refused']
    assert 0 < counters['stopped_at'] < 200
    assert result['stopped_thermostat'][0] > 0
    # Back from where it stopped, to the start bit for bit.
    assert_same_state(result, 'back', 'start')


SETUP = fcc_box('lj', 4, 1.5, 87287, mom=True) + '\ntimestep 0.00390625\n'

SCRIPT = SETUP + """reversible nvt temp 1.5 tdamp 0.5
run 0
write_data start.data nofix
reversible anchor
run 100
write_restart half.restart
timestep -0.00390625
run 100
reversible check
"""

#: A new LAMMPS instance from the restart file, back to the start; LAMMPS's own
#: run 0 before reversible nvt initialises LAMMPS, which would drop the
#: file's thermostat if the runner had not taken it at read_restart.
BACK = """units lj
read_restart half.restart
mass 1 1.0
pair_coeff 1 1 1.0 1.0
timestep -0.00390625
run 0
reversible nvt temp 1.5 tdamp 0.5
run 100
write_data end.data nofix
"""


def sections(path):
    """The Atoms and Velocities lines of a data file, sorted."""
    lines, keep = [], False
    for line in path.read_text().splitlines():
        word = line.split('#')[0].strip()
        if word in ('Atoms', 'Velocities'):
            keep = True
        elif word in ('Masses', 'Pair Coeffs', 'Bonds'):
            keep = False
        elif keep and word:
            lines.append(word)
    return sorted(lines)


def test_script_runs_out_and_back_and_from_a_restart_file(tmp_path):
    (tmp_path / 'in.nvt').write_text(SCRIPT)
    done = run_here('-m', 'ase_reversible.lammps', 'in.nvt', '-log',
                    'none', cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert re.search(r'exact run of 100 steps \(0 to 100\).*thermostat s '
                     r'[0-9.]+ pi \S+ T [0-9.]+ \(target 1.5\)', done.stdout)
    assert ('all 256 atoms, and the thermostat (s, pi, clock) are at the '
            'anchor, bit for bit') in done.stdout
    (tmp_path / 'in.back').write_text(BACK)
    done = run_here('-m', 'ase_reversible.lammps', 'in.back', '-log',
                    'none', cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert 'thermostat from the restart file: s 0.' in done.stdout
    assert re.search(r'exact run of 100 steps \(100 to 200\).*thermostat s '
                     r'1 pi 0 .*real time 0; back at \S+ tau/day', done.stdout)
    start = sections(tmp_path / 'start.data')
    assert len(start) == 2 * 256
    assert sections(tmp_path / 'end.data') == start


def test_script_refuses_nvt_without_the_compiled_step(tmp_path,
                                                      monkeypatch):
    # No compiler, and an empty cache: the plugin cannot be had.  In a
    # process of its own: this one may have loaded the plugin.
    monkeypatch.setenv('CXX', str(tmp_path / 'no-such-compiler'))
    monkeypatch.setenv('ASE_REVERSIBLE_CACHE', str(tmp_path / 'cache'))
    (tmp_path / 'in.nvt').write_text(SETUP + 'reversible nvt temp 1.5 '
                                     'tdamp 0.5\nrun 10\n')
    done = launch(1, '-m', 'ase_reversible.lammps', 'in.nvt', '-log', 'none',
                  cwd=tmp_path)
    assert done.returncode == 1
    assert 'needs the compiled step' in done.stderr
    assert 'python -m ase_reversible lammps build' in done.stderr
    assert 'exact run' not in done.stdout


def test_bad_settings_are_refused_and_a_moving_centre_warned(tmp_path):
    counters = job(1, 'refused', tmp_path)['counters']
    refused = counters['refused']
    assert len(refused) == 3
    assert 'only on the compiled path' in refused[0]
    assert 'temperature must be positive' in refused[1]
    assert 'tdamp must be positive' in refused[2]
    # Then the atoms set moving as a whole (0.5 in x): warned, as for the
    # ASE thermostat, since N_f = 3N - 3 assumes zero total momentum.
    assert len(counters['moving']) == 1
    assert 'mom yes' in counters['moving'][0]


@SLOW
def test_samples_the_canonical_kinetic_energy_as_fix_nvt_does(tmp_path):
    # 256 LJ atoms at T* = 1.5 (density 0.8442: a liquid), equilibrated
    # by LAMMPS's fix nvt for 2000 steps; then 20,000 exact steps of 2^-8
    # tau (tdamp 0.5), the kinetic temperature every 10, against LAMMPS's
    # fix nvt continuing from the same equilibrated state.  The canonical
    # kinetic energy is a gamma distribution of shape N_f / 2.
    stats = pytest.importorskip('scipy.stats',
                                reason='the KS test needs scipy')
    result = job(1, 'sample', tmp_path, system='lj', steps=20000, every=10)
    counters = result['counters']
    n_f = counters['dof']
    assert n_f == 3 * 256 - 3
    canonical = stats.gamma(n_f / 2, scale=2 * 1.5 / n_f)
    found = {}
    for name, temperatures in counters['kinetic'].items():
        temperatures = np.array(temperatures)
        assert len(temperatures) == 2000
        found[name] = (temperatures.mean(),
                       stats.kstest(temperatures, canonical.cdf).pvalue)
    print(found)
    mean, p = found['exact']
    assert abs(mean / 1.5 - 1) < 0.01
    assert p > 0.01


def test_a_step_refused_after_its_drift_is_undone_exactly(tmp_path):
    # fix addforce adds 1e300 from step 21: that step drifts, then its kick
    # is out of range; fix_modify undo takes back the drift, the first
    # half-kick and the thermostat's shears.
    result = job(1, 'blowup', tmp_path, system='lj', steps=100)
    counters = result['counters']
    assert counters['refused'].startswith('FloatingPointError: forces at '
                                          'step 21')
    assert counters['stopped_at'] == 20
    assert not np.array_equal(result['stopped_x'], result['start_x'])
    assert_same_state(result, 'back', 'start')
