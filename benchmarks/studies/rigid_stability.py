"""The largest stable time step of rigid TIP3P water under
ReversibleVerlet: 27 waters from the relaxed start of benchmarks/rigid.py,
1,000 steps at each time step, the energy check at its default (a drift of
the total energy beyond the kinetic energy at the anchor stops the run);
the drift of the total energy per molecule over the steps taken and
whether the run stopped, and where (``--only rigid_stability``: ~2
minutes).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))

import common  # noqa: E402,F401  (first: pins BLAS threads before numpy)

import warnings  # noqa: E402

from rigid import fresh, relaxed  # noqa: E402

TIMESTEPS_FS = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0)


def case(start, dt_fs, steps):
    from ase import units

    from ase_reversible import ReversibleVerlet, UnstableIntegrationError
    atoms = fresh(start)
    dyn = ReversibleVerlet(atoms, dt_fs * units.fs)
    n = len(atoms) // 3
    e0 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
    stopped, reason = None, None
    try:
        dyn.run(steps)
    except UnstableIntegrationError as error:
        stopped, reason = dyn.nsteps, str(error).split(':')[0]
    e1 = atoms.get_potential_energy() + atoms.get_kinetic_energy()
    out = {'timestep_fs': dt_fs, 'n_waters': n, 'steps': steps,
           'stopped_at': stopped, 'reason': reason,
           'energy_change_per_molecule': float(e1 - e0) / n}
    print(f"  {dt_fs:g} fs: stopped at {stopped}, energy change "
          f"{out['energy_change_per_molecule']:+.2e} eV/molecule",
          flush=True)
    return out


def run(quick=False):
    warnings.simplefilter('ignore')
    start = relaxed(27)
    steps = 200 if quick else 1000
    return {'cases': [case(start, dt, steps) for dt in TIMESTEPS_FS]}
