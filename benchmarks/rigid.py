"""Rigid TIP3P water: ReversibleVerlet's rigid bodies against ASE's
VelocityVerlet with FixBondLengths (RATTLE), from the same start
(``--only rigid``: ~17 minutes, ~30 s with ``--quick``).

The start: waters on a 3.1 Å lattice, turned at random, periodic, relaxed
by 600 steps of 0.5 fs with the momenta set back to 300 K every 200.
Measured: the total energy's fluctuation (standard deviation) and drift
over a run, the cost per step (the two integrators alternating, medians),
a round trip out and back, and after a long run the largest departure
of an O-H or H-H distance from its target and of an orientation
quaternion's length from 1.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import statistics
import time
import warnings

import numpy as np

#: (waters per side, cut-off Å) of the cases.
SIZES = {27: (3, 4.5), 64: (4, 6.0), 216: (6, 9.0)}


def relaxed(n_waters):
    """The start of every measurement on ``n_waters`` waters."""
    from ase import units

    from ase_reversible import ReversibleVerlet
    from ase_reversible.app.systems import water_box
    side, rc = SIZES[n_waters]
    box = water_box(side, rc=rc)
    for _ in range(3):
        ReversibleVerlet(box, 0.5 * units.fs, energy_check=0).run(200)
        box.set_momenta(box.get_momenta()
                        * np.sqrt(300.0 / box.get_temperature()))
        box.info.clear()
    return box


def fresh(start):
    from ase.calculators.tip3p import TIP3P
    atoms = start.copy()
    atoms.calc = TIP3P(rc=start.calc.rc)
    atoms.set_constraint(start.constraints[0].copy())
    atoms.constraints[0].bondlengths = None
    return atoms


def integrators():
    from ase import units
    from ase.md.verlet import VelocityVerlet

    from ase_reversible import ReversibleVerlet
    return {'ase': lambda atoms, dt: VelocityVerlet(atoms, dt * units.fs),
            'exact': lambda atoms, dt: ReversibleVerlet(
                atoms, dt * units.fs, energy_check=0)}


def energy_case(start, dt, steps):
    """Energy fluctuation and drift (eV per molecule) of both."""
    out = {'n_waters': len(start) // 3, 'timestep_fs': dt, 'steps': steps}
    for name, make in integrators().items():
        atoms = fresh(start)
        dyn = make(atoms, dt)
        energies = []
        for _ in range(steps):
            dyn.run(1)
            energies.append(atoms.get_potential_energy()
                            + atoms.get_kinetic_energy())
        e = np.array(energies) / out['n_waters']
        slope = np.polyfit(np.arange(steps) * dt * 1e-3, e, 1)[0]
        out[name] = {'std': float(e.std()), 'drift_per_ps': float(slope),
                     'temperature': float(atoms.get_temperature())}
    print(f"  energy N={out['n_waters']} dt={dt}: ase std "
          f"{out['ase']['std']:.2e} exact {out['exact']['std']:.2e}",
          flush=True)
    return out


def cost_case(start, dt, steps, rounds):
    """Seconds per step of both, alternating, medians over ``rounds``."""
    runners = {name: make(fresh(start), dt)
               for name, make in integrators().items()}
    per = {name: [] for name in runners}
    for name, dyn in runners.items():
        dyn.run(1)
    for _ in range(rounds):
        for name, dyn in runners.items():
            n = steps[name]
            tic = time.perf_counter()
            dyn.run(n)
            per[name].append((time.perf_counter() - tic) / n)
    seconds = {name: statistics.median(v) for name, v in per.items()}
    out = {'n_waters': len(start) // 3, 'timestep_fs': dt,
           'rounds': rounds, 'steps': steps, 'seconds': seconds,
           'ratio': seconds['exact'] / seconds['ase']}
    print(f"  cost N={out['n_waters']}: ase {seconds['ase'] * 1e3:.0f} ms, "
          f"exact {seconds['exact'] * 1e3:.1f} ms", flush=True)
    return out


def long_case(start, dt, steps):
    """Out and back bit for bit, and the shapes after ``steps`` steps."""
    from ase import units
    from ase.calculators.tip3p import angleHOH, rOH

    from ase_reversible import ReversibleVerlet
    atoms = fresh(start)
    dyn = ReversibleVerlet(atoms, dt * units.fs)
    first = dyn.counts
    tic = time.perf_counter()
    dyn.run(steps)
    n = len(atoms) // 3
    oh = np.concatenate([atoms.get_distances(3 * i, [3 * i + 1, 3 * i + 2],
                                             mic=True) for i in range(n)])
    hh = np.array([atoms.get_distance(3 * i + 1, 3 * i + 2, mic=True)
                   for i in range(n)])
    target_hh = 2 * rOH * np.sin(np.radians(angleHOH) / 2)
    q = dyn.counts['orientation'] * dyn.system.q.quantum
    length = np.sqrt((q * q).sum(axis=1))
    dyn.reverse().run(steps)
    back = dyn.counts
    out = {'n_waters': n, 'timestep_fs': dt, 'steps': steps,
           'exact': all(np.array_equal(first[k], back[k]) for k in first),
           'bond_error': float(max(np.abs(oh - rOH).max(),
                                   np.abs(hh - target_hh).max())),
           'quaternion_length_error': float(np.abs(length - 1.0).max()),
           'seconds': time.perf_counter() - tic}
    print(f"  long N={n} dt={dt} {steps} steps: exact {out['exact']}, "
          f"bonds {out['bond_error']:.1e}, |q|-1 "
          f"{out['quaternion_length_error']:.1e}", flush=True)
    return out


def run(quick=False):
    warnings.simplefilter('ignore')
    # ASE's RATTLE takes about 2 s a step: the quick mode (run by the
    # long tier of the tests) asks it for 8 steps in all.
    starts = {n: relaxed(n) for n in ((27,) if quick else (27, 64, 216))}
    results = {'energy': [energy_case(starts[27], dt, 4 if quick else 200)
                          for dt in ((1.0,) if quick else (1.0, 2.0))]}
    results['cost'] = [
        cost_case(starts[n], 1.0, {'ase': 1 if quick else 2, 'exact': 20},
                  1 if quick else 5)
        for n in sorted(starts)]
    long_sizes = ((27, 2.0, 200),) if quick else (
        (27, 2.0, 20_000), (64, 2.0, 10_000))
    results['long'] = [long_case(starts[n], dt, steps)
                       for n, dt, steps in long_sizes]
    return results


if __name__ == '__main__':
    import json
    import sys
    print(json.dumps(run('--quick' in sys.argv), indent=1))
