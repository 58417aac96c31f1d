"""Rigid TIP3P water at 300 K, run out and back exactly, and resumed from
a frame.

:class:`~ase_reversible.ReversibleLangevin` on a periodic box of TIP3P
waters (ASE's calculator), each held rigid by ``FixBondLengths`` on its
three bonds, as for ASE's ``VelocityVerlet`` with RATTLE:

1. build the box (waters on a 3.1 Å lattice, turned at random, thermal
   momenta) and attach the thermostat at 300 K, 2 fs steps, writing a
   trajectory;
2. run: every molecule is an exact rigid body, its bonds held to the
   last bits;
3. ``reverse()`` and run the same number of steps: back where it
   started, bit for bit, in every exact variable;
4. read the middle frame with ``ase.io.read``, set the constraint and a
   calculator again and construct a new ``ReversibleLangevin`` with the
   buffer file written there: the resumed run reproduces the original's
   last frame, bit for bit.

Run it::

    python examples/rigid_water.py --out DIR            # about 20 s
    python examples/rigid_water.py --out DIR --quick    # about 3 s

It writes ``DIR/rigid_water.traj`` (look at it with ``ase gui``) and
``DIR/rigid_water.npz`` (the buffer), and prints the checks; :func:`main`
returns them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from ase import units
from ase.calculators.tip3p import TIP3P, rOH
from ase.io import read

from ase_reversible import ReversibleLangevin
from ase_reversible.app.systems import water_bonds, water_box

TEMPERATURE_K = 300.0
FRICTION = 0.01 / units.fs
TIMESTEP = 2 * units.fs
SEED = 11


def thermostat(atoms, **kwargs):
    return ReversibleLangevin(atoms, TIMESTEP, TEMPERATURE_K, FRICTION,
                              seed=SEED, **kwargs)


def main(out_dir='.', quick=False):
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    side, steps = (3, 40) if quick else (4, 400)
    box = water_box(side, TEMPERATURE_K)
    path = out_dir / 'rigid_water.traj'
    buffer = out_dir / 'rigid_water.npz'
    half = steps // 2
    with thermostat(box, trajectory=str(path),
                    loginterval=half) as dyn:
        start = dyn.counts
        dyn.run(half)
        dyn.write_buffer(buffer)
        dyn.run(steps - half)
        end = dyn.counts
        bond_error = max(abs(box.get_distance(3 * i, 3 * i + 1, mic=True)
                             - rOH) for i in range(side**3))
        temperature = box.get_temperature()
        dyn.observers.clear()  # the way back writes no frames
        dyn.reverse().run(steps)
        exact_return = all(np.array_equal(start[k], v)
                           for k, v in dyn.counts.items())
    frame = read(path, index=1)
    frame.set_constraint(water_bonds(side**3))
    frame.calc = TIP3P(rc=box.calc.rc)
    resumed = thermostat(frame, buffer=str(buffer))
    resumed.run(steps - half)
    exact_resume = all(np.array_equal(end[k], v)
                       for k, v in resumed.counts.items())
    result = {'trajectory': str(path), 'frames': len(read(path, ':')),
              'exact_return': exact_return, 'exact_resume': exact_resume,
              'bond_error': bond_error, 'temperature': temperature,
              'pictures': []}
    print(f'{side**3} rigid waters, {steps} steps of 2 fs at 300 K: '
          f'{temperature:.0f} K at the end, largest O-H error '
          f'{bond_error:.1e} Å')
    print(f'out and back bit for bit: {exact_return}; resumed from the '
          f'middle frame bit for bit: {exact_resume}')
    return result


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='.', help='folder for the files')
    parser.add_argument('--quick', action='store_true',
                        help='a smaller box and fewer steps')
    arguments = parser.parse_args()
    main(arguments.out, arguments.quick)
