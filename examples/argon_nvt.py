"""A cold argon cluster heated by a Langevin thermostat, and un-heated exactly.

:class:`~ase_reversible.ReversibleLangevin` on a 147-atom argon icosahedron
with ASE's Lennard-Jones calculator:

1. start the cluster at 10 K and attach the thermostat at 60 K (friction
   0.01 / fs), writing a trajectory and a log as any ASE dynamics does;
2. run: the thermostat heats the cluster, its friction dropping digits
   into the information buffer and its noise drawn from the seed;
3. write the buffer at the middle frame (``write_buffer``);
4. ``reverse()`` and run the same number of steps: the noise is taken back
   and the friction undone from the buffer, and the cluster is back at
   10 K, bit for bit where it started, the buffer empty;
5. read the middle frame with ``ase.io.read``, attach a calculator and
   construct a new ``ReversibleLangevin`` with the buffer file: the resumed
   run reproduces every later frame of the original, bit for bit.

Run it::

    python examples/argon_nvt.py --out DIR            # about 25 s
    python examples/argon_nvt.py --out DIR --quick    # about 5 s

It writes ``DIR/argon_nvt.traj`` (look at it with ``ase gui``),
``DIR/argon_nvt.log``, ``DIR/argon_nvt.npz`` (the buffer) and
``DIR/argon_nvt.png`` (the temperature out and back), and prints the
checks; :func:`main` returns them.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.calculators.lj import LennardJones
from ase.cluster import Icosahedron
from ase.io import read

from ase_reversible import ReversibleLangevin
from ase_reversible.app.systems import thermalize

TEMPERATURE_K = 60.0
FRICTION = 0.01 / units.fs
TIMESTEP = 5 * units.fs
LOGINTERVAL = 10
SEED = 7


def argon_lj():
    """ASE's Lennard-Jones calculator with argon's parameters (eV, Å)."""
    return LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)


def thermostat(atoms, **kwargs):
    return ReversibleLangevin(atoms, TIMESTEP, TEMPERATURE_K, FRICTION,
                              seed=SEED, **kwargs)


def main(out_dir='.', quick=False) -> dict:
    """Run the workflow; return the checks.

    Returns a dict: ``trajectory`` (its path), ``frames`` (frames in it),
    ``exact_return`` (True if the reversed run ended bitwise at the start,
    with the buffer empty), ``exact_resume`` (True if the run resumed from
    the middle frame and the buffer file reproduced every later frame
    bitwise), ``temperatures_K`` (at the start, the turn and the end),
    ``buffer_bytes`` (the buffer's size at the turn), ``pictures`` and
    ``seconds``.
    """
    started = time.perf_counter()
    steps = 200 if quick else 1000
    middle = steps // 2
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj_path, log_path = out / 'argon_nvt.traj', out / 'argon_nvt.log'
    buffer_path = out / 'argon_nvt.npz'

    atoms = Icosahedron('Ar', 4, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    thermalize(atoms, 10.0, seed=SEED)
    atoms.calc = argon_lj()
    dyn = thermostat(atoms, trajectory=str(traj_path), logfile=str(log_path),
                     loginterval=LOGINTERVAL)
    start = dyn.state
    out_T, back_T = [], []
    dyn.attach(lambda: out_T.append(atoms.get_temperature()),
               interval=LOGINTERVAL)
    dyn.run(middle)
    dyn.write_buffer(buffer_path)
    dyn.run(steps - middle)
    turn_T = atoms.get_temperature()
    buffer_bytes = sum(b.nbytes for b in dyn.friction_step.buffers.values())
    dyn.close()

    dyn.observers.clear()
    dyn.attach(lambda: back_T.append(atoms.get_temperature()),
               interval=LOGINTERVAL)
    dyn.reverse()
    dyn.run(steps)
    end = dyn.state
    exact_return = (np.array_equal(end.ix_nc, start.ix_nc)
                    and np.array_equal(end.ip_nc, start.ip_nc)
                    and all(b.is_empty()
                            for b in dyn.friction_step.buffers.values()))

    frames = read(traj_path, ':')
    resumed = frames[middle // LOGINTERVAL].copy()
    resumed.calc = argon_lj()
    again = thermostat(resumed, buffer=buffer_path)
    exact_resume = True
    for frame in frames[middle // LOGINTERVAL + 1:]:
        again.run(LOGINTERVAL)
        exact_resume &= (np.array_equal(resumed.positions, frame.positions)
                         and np.array_equal(resumed.get_momenta(),
                                            frame.get_momenta()))

    picture = out / 'argon_nvt.png'
    _plot(picture, out_T, back_T)
    result = {'trajectory': str(traj_path), 'frames': len(frames),
              'exact_return': bool(exact_return),
              'exact_resume': bool(exact_resume),
              'temperatures_K': (out_T[0], turn_T, back_T[-1]),
              'buffer_bytes': buffer_bytes, 'pictures': [str(picture)],
              'seconds': time.perf_counter() - started}
    return result


def _plot(path, out_T, back_T):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    t_out = np.arange(len(out_T)) * LOGINTERVAL * TIMESTEP / units.fs
    # The way back is observed from its first step on, not at the turn.
    t_back = t_out[::-1][1:len(back_T) + 1]
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=120)
    ax.plot(t_out, out_T, lw=2.5, label='out (thermostat at 60 K)')
    ax.plot(t_back, back_T, '--', lw=1.5, label='back (reverse())')
    ax.axhline(TEMPERATURE_K, color='grey', lw=0.8)
    ax.set_xlabel('time (fs)')
    ax.set_ylabel('temperature (K)')
    ax.set_title('Ar147 heated by ReversibleLangevin, then run back')
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', default='.', help='output directory')
    parser.add_argument('--quick', action='store_true', help='short run')
    args = parser.parse_args()
    r = main(args.out, args.quick)
    t0, t1, t2 = r['temperatures_K']
    print(f'temperature: {t0:.1f} K at the start, {t1:.1f} K at the turn, '
          f'{t2:.1f} K back at the start')
    print(f'buffer at the turn: {r["buffer_bytes"]} bytes')
    print(f'back at the start bit for bit, buffer empty: {r["exact_return"]}')
    print(f'resumed from the middle frame and its buffer, every later frame '
          f'bit for bit: {r["exact_resume"]}')
    print(f'{r["seconds"]:.1f} s; trajectory {r["trajectory"]}')
