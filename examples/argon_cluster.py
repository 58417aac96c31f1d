"""An argon cluster run forward, back to its start, and resumed from a frame.

The everyday workflow with :class:`~ase_reversible.ReversibleVerlet`, top
to bottom, on a 147-atom argon icosahedron with ASE's Lennard-Jones
calculator:

1. build the cluster and attach the calculator;
2. bring it to 40 K with ASE's Langevin thermostat;
3. run it at constant energy with ``ReversibleVerlet``, writing a
   trajectory and a log as any ASE dynamics does;
4. ``reverse()`` and run the same number of steps: the atoms are back at
   the start of step 3, bit for bit;
5. read a frame from the middle of the trajectory with ``ase.io.read``,
   attach a calculator, construct a new ``ReversibleVerlet``: the resumed
   run reproduces every later frame of the original, bit for bit.

Run it::

    python examples/argon_cluster.py --out DIR            # about 20 s
    python examples/argon_cluster.py --out DIR --quick    # about 3 s

It writes ``DIR/argon_cluster.traj`` (look at it with ``ase gui``),
``DIR/argon_cluster_resumed.traj``, ``DIR/argon_cluster.log`` and
``DIR/argon_cluster.png``, and prints the checks; :func:`main` returns
them.  Units are ASE's: Å, eV, amu, and time in ASE units
(``ase.units.fs`` converts femtoseconds).
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
from ase.md.langevin import Langevin
from ase.md.velocitydistribution import Stationary, ZeroRotation

from ase_reversible import ReversibleVerlet

TEMPERATURE_K = 40.0
#: Over the 5 ps run the total energy stays within 1e-4 eV of its start
#: (the kinetic energy is 0.7 eV): see the log.
TIMESTEP = 5 * units.fs
#: Steps between trajectory frames (and log lines).
LOGINTERVAL = 10
SEED = 42


def argon_lj():
    """ASE's Lennard-Jones calculator with argon's parameters (eV, Å).

    Any ASE calculator will do.  ``ase_reversible.LennardJones`` takes the
    same parameters (its potential is switched off smoothly towards ``rc``
    instead of shifted) and runs this cluster several times faster.
    """
    return LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)


def main(out_dir='.', quick=False) -> dict:
    """Run the workflow; return the checks.

    Returns a dict: ``trajectory`` (path of the trajectory), ``frames``
    (number of frames in it), ``exact_return`` (True if the reversed run
    ended bitwise where the forward run started), ``exact_resume`` (True if
    the run resumed from a frame reproduced every later frame bitwise),
    ``resumed_from`` (index of that frame), ``pictures`` (paths of the
    PNGs written) and ``seconds``.
    """
    started = time.perf_counter()
    thermalise_steps, steps = (100, 200) if quick else (400, 1000)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    # 1. A 147-atom icosahedron.  The cell only gives `ase gui` a box to
    # draw: the cluster is not periodic.
    atoms = Icosahedron('Ar', noshells=4, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    atoms.calc = argon_lj()

    # 2. Thermalise; the full run gives the thermostat 2 ps.
    heating = thermalise(atoms, TEMPERATURE_K, thermalise_steps)
    # Without the drift and spin the thermostat left, the cluster stays put
    # in the middle of its box during the run.
    Stationary(atoms)
    ZeroRotation(atoms)

    # 3. to 5.
    checks = run_back_and_resume(atoms, argon_lj, out / 'argon_cluster',
                                 steps)
    picture = out / 'argon_cluster.png'
    draw(picture, checks['trajectory'], checks.pop('resumed'), heating)
    return {**checks, 'pictures': [str(picture)],
            'seconds': time.perf_counter() - started}


def thermalise(atoms, temperature_K, steps):
    """Step 2: ``steps`` steps of ASE's Langevin thermostat at
    ``temperature_K``; returns the temperatures (K) every LOGINTERVAL
    steps, for the picture.

    A thermostat draws random numbers at every step, so it cannot be run
    backwards: the preparation is done with ordinary ASE dynamics, and the
    reversible part starts with the constant-energy run after it.  The
    friction couples the atoms to the heat bath within about 100 fs.
    """
    thermostat = Langevin(atoms, TIMESTEP, temperature_K=temperature_K,
                          friction=0.01 / units.fs, fixcm=False,
                          rng=np.random.default_rng(SEED))
    heating = []
    thermostat.attach(lambda: heating.append(atoms.get_temperature()),
                      interval=LOGINTERVAL)
    thermostat.run(steps)
    return heating


def run_back_and_resume(atoms, make_calc, stem, steps) -> dict:
    """Steps 3 to 5: ``steps`` steps at constant energy, as many back, and
    a run resumed from the middle frame with a new ``make_calc()``.

    Writes ``stem.traj``, ``stem.log`` and ``stem_resumed.traj``.  Returns
    a dict: ``trajectory``, ``frames``, ``exact_return``,
    ``exact_resume`` and ``resumed_from`` (as :func:`main` says), and
    ``resumed`` (the path of the resumed run's trajectory).
    """
    stem = Path(stem)
    traj_path = stem.with_suffix('.traj')
    resumed_path = stem.with_name(stem.name + '_resumed.traj')
    log_path = stem.with_suffix('.log')
    log_path.unlink(missing_ok=True)  # ASE's MDLogger appends to a log

    # 3. Constant energy, reversibly.  The constructor moves positions and
    # momenta by at most half a quantum onto its integer grid; the state it
    # leaves on the atoms is where reversal leads back to.  Atoms held by
    # FixAtoms stay exactly where they are, not even a quantum moves.
    with ReversibleVerlet(atoms, TIMESTEP, trajectory=str(traj_path),
                          logfile=str(log_path),
                          loginterval=LOGINTERVAL) as dyn:
        # Some calculators (asap3's) compute the energy only when asked,
        # and the frame is written before the logger asks: ask first, so
        # that the frames carry the energy too (`ase gui` plots it).
        dyn.insert_observer(atoms.get_potential_energy, interval=LOGINTERVAL)
        start_positions = atoms.get_positions()
        start_momenta = atoms.get_momenta()
        dyn.run(steps)

        # 4. Back to the start.  The trajectory writer is an observer and
        # keeps writing on the way back, so the file plays the run forward
        # and then backward: frame n_frames - 1 - j has the positions and
        # momenta of frame j, bit for bit.  Read the forward run alone with
        # read(path, f':{steps // LOGINTERVAL + 1}').
        dyn.reverse()
        dyn.run(steps)
    exact_return = (np.array_equal(atoms.positions, start_positions)
                    and np.array_equal(atoms.get_momenta(), start_momenta))

    # 5. Resume from the frame written at the middle of the forward run.
    # The frame carries the quanta of the grid in atoms.info['reversible'],
    # and the trajectory keeps constraints such as FixAtoms, so the new
    # integrator re-encodes it into the very integers the original run
    # had; its clock continues from the frame's time.
    forward_frames = steps // LOGINTERVAL + 1
    first = forward_frames // 2
    resumed = read(traj_path, first)
    resumed.calc = make_calc()
    with ReversibleVerlet(resumed, TIMESTEP, trajectory=str(resumed_path),
                          loginterval=LOGINTERVAL) as dyn2:
        dyn2.insert_observer(resumed.get_potential_energy,
                             interval=LOGINTERVAL)
        dyn2.run(steps - first * LOGINTERVAL)
    original = read(traj_path, f'{first}:{forward_frames}')
    again = read(resumed_path, ':')
    # Same grid: the record was used (a fresh choice of quanta can
    # coincide, and would then reproduce the frames too).
    exact_resume = dyn2.grid == dyn.grid and len(again) == len(original) \
        and all(np.array_equal(a.positions, b.positions)
                and np.array_equal(a.get_momenta(), b.get_momenta())
                for a, b in zip(again, original))
    return {'trajectory': str(traj_path),
            'frames': len(read(traj_path, ':')),
            'exact_return': bool(exact_return),
            'exact_resume': bool(exact_resume),
            'resumed_from': first,
            'resumed': resumed_path}


def draw(path, traj_path, resumed_path, heating):
    """Temperature against time: thermalisation, run, way back, resume."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.6), layout='constrained')
    plot_temperatures(ax, read(traj_path, ':'), read(resumed_path, ':'),
                      heating, TEMPERATURE_K)
    ax.legend(loc='best', fontsize=9)
    ax.set_title(f'Ar147: thermostat to {TEMPERATURE_K:g} K, then '
                 'ReversibleVerlet forward, back, and resumed', fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_temperatures(ax, frames, resumed, heating, temperature_K):
    """The temperature (K) against time (ps) on ``ax``: ``heating``, the
    thermalisation's every LOGINTERVAL steps (it ended at time 0), then
    ``frames`` (the trajectory: forward, then the way back) and
    ``resumed`` (the resumed run's frames)."""
    def curve(frames):
        # The restart record carries each frame's simulated time.
        t = [f.info['reversible']['time'] / (1000 * units.fs) for f in frames]
        return np.array(t), np.array([f.get_temperature() for f in frames])

    n = (len(frames) + 1) // 2  # forward frames; the rest is the way back
    ps = LOGINTERVAL * TIMESTEP / (1000 * units.fs)
    ax.plot(ps * np.arange(1 - len(heating), 1), heating, '-',
            color='0.6', lw=1.5, label='Langevin thermalisation')
    ax.plot(*curve(frames[:n]), '-', color='tab:blue', lw=1.5,
            label='forward')
    ax.plot(*curve(frames[n - 1:]), 'o', color='tab:orange', mfc='none',
            ms=5, label='reversed, on the way back')
    ax.plot(*curve(resumed), 'x', color='tab:green', ms=4,
            label=f'resumed from frame {n - len(resumed)}')
    ax.axvline(0.0, color='0.3', lw=0.8, ls=':')
    ax.axhline(temperature_K, color='0.3', lw=0.8, ls=':')
    ax.set_xlabel('time (ps)')
    ax.set_ylabel('temperature (K)')
    ax.grid(alpha=0.3)


def command_line(main, doc):
    """``main(--out, --quick)`` as the command line asks; its report."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument('--out', default='.', help='directory for the files')
    parser.add_argument('--quick', action='store_true',
                        help='a short run (for smoke tests)')
    args = parser.parse_args()
    return main(args.out, args.quick)


def print_checks(report):
    """Print the checks a report of :func:`run_back_and_resume` holds."""
    print(f"{report['frames']} frames in {report['trajectory']} "
          f"({report['seconds']:.1f} s)")
    print('back at the start bit for bit:', report['exact_return'])
    print(f"run resumed from frame {report['resumed_from']} reproduces the "
          'later frames bit for bit:', report['exact_resume'])
    print('view it with:  ase gui', report['trajectory'])


if __name__ == '__main__':
    print_checks(command_line(main, __doc__))
