"""Rigid TIP3P water under ReversibleLangevin and ReversibleBussi: long
runs out and back, the canonical distribution of the molecules'
translational and rotational kinetic energies and the mean temperature over the 6 N - 3 degrees of
freedom of rigid molecules with no net momentum, 64 waters, 300 K, 2 fs;
Langevin with fixcm (its noise has no net momentum), Bussi with ASE's
count of degrees of freedom (``atoms.get_number_of_degrees_of_freedom()``,
6 N), which puts its kinetic energy 3 / (6 N - 3) above that of 6 N - 3
at 300 K (``--only rigid_sampling``: ~20 minutes, ~2 with ``--quick``).

The round trips: 64 waters at 2 fs, every exact variable compared with
its start after the steps out and back.

Each molecule's rotational kinetic energy should follow Gamma(3/2, kT),
its translational one Gamma(3/2, kT (1 - 1/N)) for N equal molecules
with no net momentum; the Kolmogorov-Smirnov p-values are of all
molecules' energies sampled every 100 fs after 2 ps of equilibration
(samples closer in time are correlated, which the test does not allow
for).  The mean
temperature's standard error comes from 20 block averages.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))

import common  # noqa: E402,F401  (first: pins BLAS threads before numpy)

import math  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

from harness import block_mean  # noqa: E402
from rigid import relaxed  # noqa: E402

TEMPERATURE_K = 300.0


def gamma_ks_pvalue(samples, shape, scale):
    """Kolmogorov-Smirnov p-value of ``samples`` against Gamma(shape,
    scale) (scipy's)."""
    from scipy import stats
    return float(stats.kstest(samples, 'gamma',
                              args=(shape, 0, scale)).pvalue)


def thermostat(name, start):
    """``(atoms, dynamics)``: a copy of ``start`` with no net momentum
    under the thermostat ``name`` at 2 fs."""
    from ase import units
    from ase.md.velocitydistribution import Stationary

    from ase_reversible import ReversibleBussi, ReversibleLangevin
    atoms = start.copy()
    Stationary(atoms)  # no net momentum: 6 N - 3 degrees of freedom move
    atoms.calc = start.calc.__class__(rc=start.calc.rc)
    atoms.set_constraint(start.constraints[0].copy())
    if name == 'langevin':
        return atoms, ReversibleLangevin(atoms, 2 * units.fs,
                                         temperature_K=TEMPERATURE_K,
                                         friction=0.01 / units.fs, seed=5)
    return atoms, ReversibleBussi(atoms, 2 * units.fs,
                                  temperature_K=TEMPERATURE_K,
                                  taut=100 * units.fs, seed=5)


def round_trip(name, start, steps):
    """Out and back bit for bit under the thermostat ``name``."""
    import time
    atoms, dyn = thermostat(name, start)
    first = dyn.counts
    tic = time.perf_counter()
    dyn.run(steps)
    temperature = atoms.get_temperature()
    dyn.reverse().run(steps)
    back = dyn.counts
    out = {'thermostat': name, 'n_waters': len(atoms) // 3,
           'timestep_fs': 2.0, 'steps': steps,
           'exact': all(np.array_equal(first[k], back[k]) for k in first),
           'temperature_at_turn': float(temperature),
           'seconds': time.perf_counter() - tic}
    print(f"  {name} {steps} steps out and back: exact {out['exact']}",
          flush=True)
    return out


def sample(name, start, steps, every=50):
    from ase import units
    atoms, dyn = thermostat(name, start)
    dyn.run(1000)
    system = dyn.system
    layout = system.layout
    n = layout.n_bodies
    dof = 6 * n - 3
    translational, rotational, temperatures = [], [], []
    for _ in range(steps // every):
        dyn.run(every)
        p = system.p.floats
        spin = system.l.floats
        kt = (p * p).sum(axis=1) / (2 * layout.masses_b)
        kr = 0.5 * (spin * spin * layout.inverse_moments_bc).sum(axis=1)
        translational.append(kt)
        rotational.append(kr)
        temperatures.append(2 * (kt.sum() + kr.sum()) / (dof * units.kB))
    kT = units.kB * TEMPERATURE_K
    mean = block_mean(temperatures)
    return {'thermostat': name, 'n_waters': n, 'degrees_of_freedom': dof,
            'steps': steps, 'every': every,
            'temperature': mean['mean'],
            'temperature_error': mean['standard_error'],
            'relative_deviation': mean['mean'] / TEMPERATURE_K - 1.0,
            'ks_translational': gamma_ks_pvalue(
                np.concatenate(translational), 1.5, kT * (1.0 - 1.0 / n)),
            'ks_rotational': gamma_ks_pvalue(
                np.concatenate(rotational), 1.5, kT),
            'net_momentum': float(math.sqrt(
                (system.p.floats.sum(axis=0) ** 2).sum()))}


def run(quick=False):
    warnings.simplefilter('ignore')
    start = relaxed(27 if quick else 64)
    steps = 2000 if quick else 20000
    results = {'temperature_K': TEMPERATURE_K,
               'round_trips': [round_trip(name, start,
                                          1000 if quick else 10_000)
                               for name in ('langevin', 'bussi')],
               'cases': [sample(name, start, steps)
                         for name in ('langevin', 'bussi')]}
    for c in results['cases']:
        print(f"  {c['thermostat']}: T {c['temperature']:.1f} +- "
              f"{c['temperature_error']:.1f} K, KS "
              f"{c['ks_translational']:.2g} {c['ks_rotational']:.2g}",
              flush=True)
    return results
