"""A copper surface with an adatom run forward, back, and resumed from a frame.

The everyday workflow with :class:`~ase_reversible.ReversibleVerlet` on a
Cu(111) slab: four layers of 6 x 6 atoms, periodic along the surface, with
vacuum above and below, the bottom layer held by ``FixAtoms``, and one
adatom on top, which wanders over the surface at 600 K.  Top to bottom:

1. build the slab and attach the EMT calculator (asap3's if it is
   installed, much faster; ASE's otherwise);
2. bring it to 600 K with ASE's Langevin thermostat;
3. run it at constant energy with ``ReversibleVerlet``, writing a
   trajectory and a log as any ASE dynamics does;
4. ``reverse()`` and run the same number of steps: every atom, the adatom
   included, is back at the start of step 3, bit for bit;
5. read a frame from the middle of the trajectory with ``ase.io.read``,
   attach a calculator, construct a new ``ReversibleVerlet``: the resumed
   run reproduces every later frame of the original, bit for bit.

Run it::

    python examples/copper_surface.py --out DIR            # about 2 s
    python examples/copper_surface.py --out DIR --quick    # about 1 s

Those times are with asap3's EMT; with ASE's own EMT they were 45 s and
9 s.  It writes ``DIR/copper_surface.traj`` (look at it with ``ase gui``),
``DIR/copper_surface_resumed.traj``, ``DIR/copper_surface.log`` and
``DIR/copper_surface.png``, and prints the checks; :func:`main` returns
them.  Units are ASE's: Å, eV, amu, and time in ASE units
(``ase.units.fs`` converts femtoseconds).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.build import add_adsorbate, fcc111
from ase.constraints import FixAtoms
from ase.io import read
from ase.md.langevin import Langevin

from ase_reversible import ReversibleVerlet

try:  # asap3 is an optional extra, much faster
    from asap3 import EMT
    EMT_NAME = 'asap3.EMT'
except ImportError:
    from ase.calculators.emt import EMT
    EMT_NAME = 'ase.calculators.emt.EMT'

TEMPERATURE_K = 600.0
#: Over the 5 ps run the total energy stays within 0.02 eV of its start
#: (the kinetic energy is 8 eV): see the log.
TIMESTEP = 5 * units.fs
#: Steps between trajectory frames (and log lines).
LOGINTERVAL = 10
LAYERS = 4
SEED = 42


def main(out_dir='.', quick=False) -> dict:
    """Run the workflow; return the checks.

    Returns a dict: ``trajectory`` (path of the trajectory), ``frames``
    (number of frames in it), ``exact_return`` (True if the reversed run
    ended bitwise where the forward run started), ``exact_resume`` (True if
    the run resumed from a frame reproduced every later frame bitwise),
    ``resumed_from`` (index of that frame), ``pictures`` (paths of the
    PNGs written), ``calculator`` (which EMT
    was used) and ``seconds``.
    """
    started = time.perf_counter()
    thermalise_steps, steps = (100, 200) if quick else (500, 1000)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj_path = out / 'copper_surface.traj'
    resumed_path = out / 'copper_surface_resumed.traj'
    log_path = out / 'copper_surface.log'
    log_path.unlink(missing_ok=True)  # ASE's MDLogger appends to a log

    # 1. The slab: fcc111 with vacuum is periodic along x and y only.
    # fcc111 tags the layers 1 (top) to LAYERS (bottom); the adatom, put on
    # a hollow site in the middle of the surface, gets tag 0 and is the
    # last atom.
    atoms = fcc111('Cu', size=(6, 6, LAYERS), vacuum=10.0)
    add_adsorbate(atoms, 'Cu', height=2.0, position='fcc', offset=(3, 3))
    atoms.set_constraint(FixAtoms(mask=atoms.get_tags() == LAYERS))
    atoms.calc = EMT()

    # 2. Thermalise.  A thermostat draws random numbers at every step, so
    # it cannot be run backwards: the preparation is done with ordinary ASE
    # dynamics, and the reversible part starts with the constant-energy run
    # below.  The friction couples the atoms to the heat bath within about
    # 100 fs; the full run gives it 2.5 ps.
    thermostat = Langevin(atoms, TIMESTEP, temperature_K=TEMPERATURE_K,
                          friction=0.01 / units.fs, fixcm=False,
                          rng=np.random.default_rng(SEED))
    heating = []  # temperatures for the picture
    thermostat.attach(lambda: heating.append(atoms.get_temperature()),
                      interval=LOGINTERVAL)
    thermostat.run(thermalise_steps)

    # 3. Constant energy, reversibly.  The constructor moves positions and
    # momenta by at most half a quantum onto its integer grid; the state it
    # leaves on the atoms is where reversal leads back to.  The fixed
    # bottom layer stays exactly where it is, not even a quantum moves.
    with ReversibleVerlet(atoms, TIMESTEP, trajectory=str(traj_path),
                          logfile=str(log_path),
                          loginterval=LOGINTERVAL) as dyn:
        # asap3 computes the energy only when asked, and the frame is
        # written before the logger asks: ask first, so that the frames
        # carry the energy too (`ase gui` plots it).
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
    # and the trajectory keeps the FixAtoms constraint, so the new
    # integrator re-encodes the frame into the very integers the original
    # run had; its clock continues from the frame's time.
    forward_frames = steps // LOGINTERVAL + 1
    first = forward_frames // 2
    resumed = read(traj_path, first)
    resumed.calc = EMT()
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

    picture = out / 'copper_surface.png'
    draw(picture, traj_path, resumed_path, heating)
    return {'trajectory': str(traj_path),
            'frames': len(read(traj_path, ':')),
            'exact_return': bool(exact_return),
            'exact_resume': bool(exact_resume),
            'resumed_from': first,
            'pictures': [str(picture)],
            'calculator': EMT_NAME,
            'seconds': time.perf_counter() - started}


def draw(path, traj_path, resumed_path, heating):
    """The adatom's path over the surface, and the temperature against time.

    ``heating`` holds the temperatures (K) every LOGINTERVAL steps of the
    thermalisation, which ended at time 0.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from ase.visualize.plot import plot_atoms

    frames = read(traj_path, ':')
    resumed = read(resumed_path, ':')
    n = (len(frames) + 1) // 2  # forward frames; the rest is the way back
    forward, back = frames[:n], frames[n - 1:]
    first = n - len(resumed)

    def times(frames):
        # The restart record carries each frame's simulated time.
        return np.array([f.info['reversible']['time'] for f in frames]) / (
            1000 * units.fs)

    def adatom_xy(frames):
        return np.array([f.positions[-1, :2] for f in frames])

    fig, (top, right) = plt.subplots(
        1, 2, figsize=(11.5, 4.6), layout='constrained',
        gridspec_kw={'width_ratios': (1.0, 1.1)})
    start = frames[0]
    # The slab and its periodic images around it, so that the close-up is
    # covered wherever the adatom goes.
    images = start.repeat((3, 3, 1))
    images.positions -= start.cell[0] + start.cell[1]
    # Darker copper deeper down shows the hollow sites between top atoms.
    shades = {0: '#3060c0', 1: '#e0a47c', 2: '#b0714c', 3: '#804f34'}
    colors = [shades.get(tag, '#804f34') for tag in images.get_tags()]
    path_xy = adatom_xy(forward)
    # With a bounding box (Å) plot_atoms draws the point (x, y) at
    # (x - xlo, y - ylo) on the axes.
    centre = 0.5 * (path_xy.min(axis=0) + path_xy.max(axis=0))
    size = np.array([11.0, 8.5])
    lo = centre - size / 2
    plot_atoms(images, top, radii=0.9, colors=colors, show_unit_cell=0,
               bbox=(*lo, *(lo + size)))
    for xy, style in ((path_xy, dict(color='k', lw=1.2, label='forward')),
                      (adatom_xy(back), dict(ls='none', marker='o', ms=4,
                                             mfc='none', color='tab:orange',
                                             label='way back')),
                      (adatom_xy(resumed), dict(ls='none', marker='x', ms=3,
                                                color='tab:green',
                                                label='resumed'))):
        top.plot(xy[:, 0] - lo[0], xy[:, 1] - lo[1], **style)
    top.legend(loc='lower left', fontsize=8, title='adatom path, every 50 fs',
               title_fontsize=8, framealpha=0.9)
    top.set_title('close-up, top view at time 0: the adatom (blue) and its '
                  'path', fontsize=10)

    ps = LOGINTERVAL * TIMESTEP / (1000 * units.fs)
    right.plot(ps * np.arange(1 - len(heating), 1), heating, '-',
               color='0.6', lw=1.5, label='Langevin thermalisation')
    right.plot(times(forward), [f.get_temperature() for f in forward], '-',
               color='tab:blue', lw=1.5, label='forward')
    right.plot(times(back), [f.get_temperature() for f in back], 'o',
               color='tab:orange', mfc='none', ms=5,
               label='reversed, on the way back')
    right.plot(times(resumed), [f.get_temperature() for f in resumed], 'x',
               color='tab:green', ms=4, label=f'resumed from frame {first}')
    right.axvline(0.0, color='0.3', lw=0.8, ls=':')
    right.axhline(TEMPERATURE_K, color='0.3', lw=0.8, ls=':')
    right.set_xlabel('time (ps)')
    right.set_ylabel('temperature (K)')
    right.legend(loc='lower right', fontsize=8)
    right.grid(alpha=0.3)
    right.set_title(f'thermostat to {TEMPERATURE_K:g} K, then '
                    'ReversibleVerlet', fontsize=10)
    fig.suptitle(f'Cu(111) slab with an adatom, {len(start)} atoms, '
                 'bottom layer fixed', fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='.', help='directory for the files')
    parser.add_argument('--quick', action='store_true',
                        help='a short run (for smoke tests)')
    args = parser.parse_args()
    report = main(args.out, args.quick)
    print('calculator:', report['calculator'])
    print(f"{report['frames']} frames in {report['trajectory']} "
          f"({report['seconds']:.1f} s)")
    print('back at the start bit for bit:', report['exact_return'])
    print(f"run resumed from frame {report['resumed_from']} reproduces the "
          'later frames bit for bit:', report['exact_resume'])
    print('view it with:  ase gui', report['trajectory'])
