"""The same bits on any number of ranks: LAMMPS inputs run on 1 to 4 ranks
and two processor grids, their final states compared bit for bit.

The cases for tests/test_lammps_ranks.py, and a command::

    python tests/lammps_ranks.py [--full] [--only lj chain ...]

Each case is one of LAMMPS's bench inputs (or an input of the same
system) with ``reversible nve`` (or ``reversible nvt``) and a velocity
grid fine enough that the guard flags kicks at many steps, run out, its
state written with ``write_dump`` at full precision, then run back and
checked against its start.  The command runs every case at the sizes of
the issue's bar (``--full``: bench sizes, 1,000 steps) or the tests'
(smaller boxes, fewer steps), on every layout of ``LAYOUTS``, plus a
restart written on 2 ranks and continued on 3, and prints per case
whether the states agree, how many steps were recomputed and the loop
time of each run.
"""

import argparse
import re
import tempfile
from pathlib import Path

import numpy as np

from lammps_inputs import bench_dir, copy_bench_files, launch

#: (ranks, processors command or ''): the layouts every case runs on.
LAYOUTS = ((1, ''), (2, ''), (2, 'processors 2 1 1'), (3, ''),
           (4, ''), (4, 'processors 4 1 1'))

#: Columns of a state: the dumps hold them at full precision.
COLUMNS = 'id type x y z ix iy iz vx vy vz'


#: name -> (input file, power-of-two time step, the exact command's words,
#: edits of the input (pattern, replacement), (steps, box multiplier) in
#: the tests and in the full runs).  The velocity quanta are the finest
#: the drift allows for each box (the run refuses finer ones): the guard
#: then flags kicks at many steps.
CASES = {
    'lj': ('in.lj', 2.0**-8, 'nve velocity_quantum {q}',
           [(r'fix\s+1 all nve', '')], (150, 0.5), (1000, 1)),
    'lj nvt': ('in.lj', 2.0**-8,
               'nvt temp 1.44 tdamp 0.5 velocity_quantum {q}',
               [(r'fix\s+1 all nve', '')], (250, 0.5), (1000, 1)),
    'chain': ('in.chain', 2.0**-6, 'nve velocity_quantum {q}',
              [(r'fix\s+1 all nve', ''), (r'fix\s+2 all langevin.*', ''),
               (r'timestep\s+0.012', '')], (60, None), (1000, None)),
    # EAM has no per-pair form of its densities in LAMMPS's interface: the
    # global setup recomputes flagged kicks, the same bits on any number
    # of ranks only where none is flagged (the default grid here).
    'eam': ('in.eam', 2.0**-8, 'nve',
            [(r'fix\s+1 all nve', ''), (r'timestep\s+0.005', '')],
            (100, 0.5), (1000, 1)),
}

#: The finest velocity quanta the drift allows, by case and box
#: multiplier (the position quantum over the time step).
QUANTA = {('lj', 0.5): 2.0**-28, ('lj', 1): 2.0**-27,
          ('lj nvt', 0.5): 2.0**-28, ('lj nvt', 1): 2.0**-27,
          ('chain', None): 2.0**-30}


def script(name, source, steps, box, layout='', restart=None):
    """The input changed as a user would: ``layout`` (a processors
    command), the exact command, the run out and a dump, the run back and
    the check.  ``restart``: ``('write', file)`` writes a restart half-way
    out; ``('read', file)`` starts from it and runs the second half."""
    _, dt, words, edits, *_ = CASES[name]
    text = source.read_text()
    for pattern, replacement in edits:
        text, count = re.subn(pattern, replacement, text, count=1)
        assert count == 1, (name, pattern)
    quantum = QUANTA.get((name, box))
    exact = 'reversible ' + words.format(q=repr(quantum))
    head, run = re.split(r'\nrun\s+\d+\s*\n?', text, maxsplit=1)
    del run
    if layout:
        head = re.sub(r'(\nunits\s+\S+\n)', rf'\1{layout}\n', head, count=1)
    dump = (f'write_dump all custom {{file}} {COLUMNS} modify format float '
            '%.17g sort id')
    if restart and restart[0] == 'read':
        head = re.sub(r'\n(read_data|lattice)[\s\S]*', '\n', head)
        head += f'read_restart {restart[1]}\n'
        if 'chain' in name:
            head += ('bond_style fene\nbond_coeff 1 30.0 1.5 1.0 1.0\n'
                     'pair_style lj/cut 1.12\npair_modify shift yes\n'
                     'pair_coeff 1 1 1.0 1.0 1.12\n')
        elif name == 'eam':
            head += 'pair_style eam\npair_coeff 1 1 Cu_u3.eam\n'
        else:
            head += 'pair_style lj/cut 2.5\npair_coeff 1 1 1.0 1.0 2.5\n'
        lines = [head, f'timestep {dt!r}', exact,
                 f'run {steps - steps // 2}', dump.format(file='out.dump'),
                 f'timestep {-dt!r}', f'run {steps}',
                 dump.format(file='back.dump')]
    else:
        lines = [head, f'timestep {dt!r}', exact, 'reversible anchor',
                 dump.format(file='start.dump')]
        if restart:
            lines += [f'run {steps // 2}', f'write_restart {restart[1]}',
                      f'run {steps - steps // 2}']
        else:
            lines += [f'run {steps}']
        lines += [dump.format(file='out.dump'), f'timestep {-dt!r}',
                  f'run {steps}', 'reversible check']
    return '\n'.join(lines) + '\n'


def read_dump(path):
    """A dump's atoms as float64 rows: ID, type, unwrapped position (``x +
    ix L``, exact on the grid: a wrapped and an unwrapped copy of the same
    state compare equal) and velocity, in the dump's order (by ID)."""
    lines = Path(path).read_text().splitlines()
    bounds = lines.index(next(line for line in lines
                              if line.startswith('ITEM: BOX BOUNDS'))) + 1
    length = np.array([float(b) - float(a) for a, b in
                       (lines[bounds + d].split()[:2] for d in range(3))])
    start = lines.index(next(line for line in lines
                             if line.startswith('ITEM: ATOMS'))) + 1
    rows = np.array([[float(word) for word in line.split()]
                     for line in lines[start:]])
    unwrapped = rows[:, 2:5] + rows[:, 5:8] * length
    return np.column_stack([rows[:, :2], unwrapped, rows[:, 8:]])


def run_case(name, layout, directory, steps, box, restart=None):
    """One run of case ``name`` on ``layout`` in ``directory``: its
    start and out states (rows in the order of the start positions), the
    output, and the counts of its first run line."""
    ranks, processors = layout
    source = bench_dir() / CASES[name][0]
    text = script(name, source, steps, box, processors, restart)
    if box is not None and box != 1:
        text = text.replace('variable        x index 1',
                            f'variable        x index {box}')
        text = re.sub(r'variable\s+([yz]) index 1',
                      rf'variable        \1 index {box}', text)
    file = directory / f'in.{name.replace(" ", "_")}'
    file.write_text(text)
    for dump in ('start.dump', 'out.dump', 'back.dump'):
        (directory / dump).unlink(missing_ok=True)
    done = launch(ranks, file, directory)
    return done


def restart_across(name, directory, steps, box, ranks=(2, 3)):
    """Case ``name`` out on ``ranks[0]`` ranks, writing a restart file
    half-way, and the file continued on ``ranks[1]``, then run back to the
    start: (the uninterrupted run's start and out rows, the continued
    run's out and back rows), all by atom ID (a restart keeps them), and
    the two processes' outputs."""
    first = run_case(name, (ranks[0], ''), directory, steps, box,
                     restart=('write', 'half.restart'))
    start, out = states(directory)
    second = run_case(name, (ranks[1], ''), directory, steps, box,
                      restart=('read', 'half.restart'))
    return ((start, out, read_dump(directory / 'out.dump'),
             read_dump(directory / 'back.dump')), (first, second))


def states(directory):
    """(start, out) rows of the dumps in ``directory``."""
    return (read_dump(directory / 'start.dump'),
            read_dump(directory / 'out.dump'))


def by_position(start, out):
    """``out``'s rows (IDs dropped) ordered by the start rows' positions,
    the start's likewise: a numbering-free comparison."""
    ids = start[:, 0]
    order = np.lexsort(start[:, 2:5].T[::-1])
    out_index = {int(i): n for n, i in enumerate(out[:, 0])}
    picked = np.array([out_index[int(i)] for i in ids[order]])
    return start[order][:, 1:], out[picked][:, 1:]


def counts(output):
    runs = re.findall(r'exact run of (\d+) steps .*?: (\d+) recomputed', output)
    return [(int(a), int(b)) for a, b in runs]


def compare_nve(name, directory, steps, box):
    """The case under LAMMPS's ``fix nve`` on every layout: how many atoms
    differ from the one-rank run, and by how much at most."""
    source = bench_dir() / CASES[name][0]
    dt = CASES[name][1]
    reference = None
    for layout in LAYOUTS:
        text = script(name, source, steps, box, layout[1])
        text = re.sub(r'reversible\s+(nve|nvt)\b.*', 'fix ref all nve', text)
        text = re.sub(r'reversible\s+anchor\n', '', text)
        text = text.split(f'timestep {-dt!r}')[0]
        if box is not None and box != 1:
            text = text.replace('variable        x index 1',
                                f'variable        x index {box}')
            text = re.sub(r'variable\s+([yz]) index 1',
                          rf'variable        \1 index {box}', text)
        file = directory / 'in.nve'
        file.write_text(text)
        done = launch(layout[0], file, directory)
        if done.returncode:
            print(f'{name:8s} fix nve {layout}: FAILED')
            continue
        start, out = by_position(*states(directory))
        if reference is None:
            reference = out
            continue
        off = np.any(out != reference, axis=1)
        print(f'{name:8s} fix nve, {layout[0]} rank(s) '
              f'{layout[1] or "default":18s}: {int(off.sum())} of {len(off)} '
              f'atoms differ from 1 rank after {steps} steps, by up to '
              f'{float(np.abs(out - reference)[:, 1:].max()):.2g}', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--full', action='store_true')
    parser.add_argument('--only', nargs='+', default=list(CASES))
    parser.add_argument('--nve', action='store_true',
                        help="LAMMPS's own fix nve instead: how far its "
                        'states on each layout are from one rank\'s')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        copy_bench_files(tmp)
        for name in args.only:
            steps, box = CASES[name][5 if args.full else 4]
            if args.nve:
                compare_nve(name, tmp, steps, box)
                continue
            reference = None
            for layout in LAYOUTS:
                done = run_case(name, layout, tmp, steps, box)
                if done.returncode:
                    print(f'{name:8s} {layout}: FAILED '
                          f'{(done.stderr or done.stdout)[-800:]}')
                    continue
                start, out = by_position(*states(tmp))
                back = 'bit for bit' in done.stdout
                loops = re.findall(r'Loop time of (\S+) on',
                                   done.stdout.split('exact grid:')[-1])
                if reference is None:
                    reference = (start, out)
                same = (np.array_equal(start, reference[0])
                        and np.array_equal(out, reference[1]))
                print(f'{name:8s} {layout[0]} rank(s) {layout[1] or "default":18s}: '
                      f'{"same" if same else "DIFFERS"} as 1 rank; back '
                      f'{"exact" if back else "OFF"}; runs {counts(done.stdout)}; '
                      f'loop {float(loops[0]) if loops else 0:.3g} s',
                      flush=True)
            if name != 'eam':
                (start, out, continued, back), _ = restart_across(
                    name, tmp, steps, box)
                print(f'{name:8s} restart written on 2 ranks, continued on '
                      f'3: {"same" if np.array_equal(out, continued) else "DIFFERS"}'
                      f' as the 2-rank run; back to the start '
                      f'{"exact" if np.array_equal(start, back) else "OFF"}',
                      flush=True)


if __name__ == '__main__':
    main()
