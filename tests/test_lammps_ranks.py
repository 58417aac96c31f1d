"""The compiled fix takes the same bits on any number of ranks.

LAMMPS's bench inputs (smaller boxes; tests/lammps_ranks.py) with a
velocity grid so fine that the guard flags kicks at many steps, run on 1
to 4 ranks (more ranks than cores: mpich takes them) and another processor
grid: the start and the state out are the same bits as on one rank, atoms
matched by their start positions (``create_atoms`` numbers them by rank),
and every run lands back on its start.  A restart file written on 2 ranks
and continued on 3 lands where the 2-rank run does.
"""

import numpy as np
import pytest

from conftest import needs_compiler
from test_lammps import mpiexec
from tiers import SLOW

import lammps_ranks
from lammps_inputs import copy_bench_files
from lammps_ranks import by_position, counts, restart_across, run_case, states

pytestmark = SLOW

#: Layouts beyond one rank: another grid on 2, 3 ranks, 4 ranks.
LAYOUTS = ((2, 'processors 2 1 1'), (3, ''), (4, ''))


@pytest.fixture(autouse=True)
def _compiler():
    mpiexec()  # skips without lammps or mpich
    needs_compiler()


@pytest.fixture
def directory(tmp_path):
    copy_bench_files(tmp_path)
    return tmp_path


def checked(done):
    assert done.returncode == 0, (done.stderr or done.stdout)[-3000:]
    assert 'at the anchor, bit for bit' in done.stdout, done.stdout[-3000:]
    return counts(done.stdout)


@pytest.mark.parametrize('name', ['lj', 'lj nvt', 'chain'])
def test_flagged_kicks_take_the_same_bits_on_any_number_of_ranks(
        name, directory):
    steps, box = lammps_ranks.CASES[name][4]
    done = run_case(name, (1, ''), directory, steps, box)
    runs = checked(done)
    # The run out recomputed at least 10 steps' flagged kicks, each on the
    # rank holding the atom (no global setup).
    assert runs[0][1] >= 10, runs
    assert 'on their own ranks' in done.stdout
    assert 'global setup' not in done.stdout
    reference = by_position(*states(directory))
    for layout in LAYOUTS:
        done = run_case(name, layout, directory, steps, box)
        assert checked(done)[0][1] >= 10
        start, out = by_position(*states(directory))
        assert np.array_equal(start, reference[0]), layout
        assert np.array_equal(out, reference[1]), layout


def test_a_restart_continued_on_another_rank_count_lands_on_the_same_state(
        directory):
    steps, box = lammps_ranks.CASES['lj'][4]
    (start, out, continued, back), (first, second) = restart_across(
        'lj', directory, steps, box)
    checked(first)
    assert second.returncode == 0, second.stderr[-3000:]
    assert counts(second.stdout)[0][1] >= 1
    assert np.array_equal(continued, out)
    assert np.array_equal(back, start)


def test_a_many_body_style_says_what_holds_and_stays_exact(directory):
    # EAM's densities have no per-pair form in LAMMPS's interface: flagged
    # kicks take the global setup, and the run says what then holds.  On
    # the default grid nothing is flagged here, and the ranks agree.
    steps, box = lammps_ranks.CASES['eam'][4]
    results = []
    for layout in ((1, ''), (3, '')):
        done = run_case('eam', layout, directory, steps, box)
        assert checked(done) == [(steps, 0), (steps, 0)]
        assert ('flagged kicks are recomputed by a global setup (a many-body '
                'pair style)') in done.stdout
        results.append(by_position(*states(directory)))
    for a, b in zip(*results):
        assert np.array_equal(a, b)
