"""A copper surface with an adatom run forward, back, and resumed from a frame.

The everyday workflow of ``argon_cluster.py`` with
:class:`~ase_reversible.ReversibleVerlet`, on a Cu(111) slab: four layers
of 6 x 6 atoms, periodic along the surface, with vacuum above and below,
the bottom layer held by ``FixAtoms``, and one adatom on top, which
wanders over the surface at 600 K.  This file builds the slab and attaches
the EMT calculator (asap3's if it is installed, much faster; ASE's
otherwise); ``argon_cluster.py``'s functions, imported from beside it, do
the rest: ASE's Langevin thermostat to 600 K, the constant-energy run and
its reversal (every atom, the adatom included, back at the start bit for
bit, the fixed layer never moved by a quantum), and the run resumed from
the middle frame, which reproduces every later frame bit for bit.

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

import time
from pathlib import Path

import numpy as np
from ase.build import add_adsorbate, fcc111
from ase.constraints import FixAtoms
from ase.io import read

# Steps 2 to 5 are argon_cluster.py's, beside this file: the workflow is
# the same whatever the atoms.
from argon_cluster import (command_line, plot_temperatures, print_checks,
                           run_back_and_resume, thermalise)

try:  # asap3 is an optional extra, much faster
    from asap3 import EMT
    EMT_NAME = 'asap3.EMT'
except ImportError:
    from ase.calculators.emt import EMT
    EMT_NAME = 'ase.calculators.emt.EMT'

# Over the 5 ps run (argon_cluster's 5 fs steps) the total energy stays
# within 0.02 eV of its start (the kinetic energy is 8 eV): see the log.
TEMPERATURE_K = 600.0
#: Atomic layers of the slab; the bottom one is held fixed.
LAYERS = 4


def main(out_dir='.', quick=False) -> dict:
    """Run the workflow; return the checks: a dict with the keys of
    ``argon_cluster.main``'s and ``calculator`` (which EMT was used)."""
    started = time.perf_counter()
    thermalise_steps, steps = (100, 200) if quick else (500, 1000)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    # 1. The slab: fcc111 with vacuum is periodic along x and y only.
    # fcc111 tags the layers 1 (top) to LAYERS (bottom); the adatom, put on
    # a hollow site in the middle of the surface, gets tag 0 and is the
    # last atom.
    atoms = fcc111('Cu', size=(6, 6, LAYERS), vacuum=10.0)
    add_adsorbate(atoms, 'Cu', height=2.0, position='fcc', offset=(3, 3))
    atoms.set_constraint(FixAtoms(mask=atoms.get_tags() == LAYERS))
    atoms.calc = EMT()

    # 2. Thermalise; the full run gives the thermostat 2.5 ps.
    heating = thermalise(atoms, TEMPERATURE_K, thermalise_steps)

    # 3. to 5.  The fixed bottom layer stays exactly where it is, and the
    # frames keep its FixAtoms.
    checks = run_back_and_resume(atoms, EMT, out / 'copper_surface', steps)
    picture = out / 'copper_surface.png'
    draw(picture, checks['trajectory'], checks.pop('resumed'), heating)
    return {**checks, 'pictures': [str(picture)], 'calculator': EMT_NAME,
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

    plot_temperatures(right, frames, resumed, heating, TEMPERATURE_K)
    right.legend(loc='lower right', fontsize=8)
    right.set_title(f'thermostat to {TEMPERATURE_K:g} K, then '
                    'ReversibleVerlet', fontsize=10)
    fig.suptitle(f'Cu(111) slab with an adatom, {len(start)} atoms, '
                 'bottom layer fixed', fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == '__main__':
    report = command_line(main, __doc__)
    print('calculator:', report['calculator'])
    print_checks(report)
