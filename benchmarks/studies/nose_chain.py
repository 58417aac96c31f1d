"""Nosé-Hoover chains of ReversibleNose: sampling, round trip
(``--only nose_chain``: ~13 minutes; stored as the nose section's
'chain').
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import copy
import time
from dataclasses import asdict, replace

import numpy as np
from ase import units
from ase.constraints import FixCom
from ase.build import bulk
from ase.md.langevin import Langevin
from harness import (NoseSampler, StudyLengths, canonical_statistics,
                     histogram_edges, nose_statistics)
from systems import (CALCULATORS, NOSE_SYSTEMS, SEED, TDAMP_STEPS,
                     THERMOSTAT_SYSTEMS, tdamp)

from ase_reversible import ReversibleNose
from ase_reversible.app.systems import thermalize
from ase_reversible.md.nose.thermostat import CHAIN_STIFFNESS

KS_LEVEL = 0.01
#: Liquid argon: fcc at rho sigma**3 = 0.84 (sigma 3.405 Å), 120 K (kT /
#: epsilon = 1.0), melted by ASE's Langevin before the thermostat starts.
AR_LIQUID_LATTICE = 5.73
AR_LIQUID_MELT_STEPS = 2000
CHAIN_LENGTHS = (1, 2, 3)


FULL = StudyLengths(equilibration=2000, sampled=60_000)
QUICK = StudyLengths(equilibration=200, sampled=1000)


def liquid_argon(repeat, temperature_K):
    atoms = bulk('Ar', 'fcc', a=AR_LIQUID_LATTICE, cubic=True) * repeat
    thermalize(atoms, temperature_K, seed=SEED)
    atoms.calc = CALCULATORS['asap3 LJ']()
    Langevin(atoms, 10 * units.fs, temperature_K=temperature_K,
             friction=0.01 / units.fs,
             rng=np.random.default_rng(SEED)).run(AR_LIQUID_MELT_STEPS)
    atoms.calc = None
    return atoms


SYSTEMS = (
    NOSE_SYSTEMS[1],
    replace(THERMOSTAT_SYSTEMS[0], label='Ar liquid', build=liquid_argon,
            temperature_K=120.0, timestep_fs=10.0),
)


class ChainSampler(NoseSampler):
    """NoseSampler with the range of every ``s_j`` and the internal kinetic
    energy of the half-kicked momenta ``(p' + h F / 2) / s_1``."""

    def __init__(self, dyn, steps):
        super().__init__(dyn, steps)
        self.low = np.full(dyn.tchain, np.inf)
        self.high = np.zeros(dyn.tchain)
        self.half_kinetic = np.full(steps + 1, np.nan)
        self.m_n1 = self.atoms.get_masses()[:, None]

    def __call__(self):
        super().__call__()
        s_j = self.dyn.thermostat_positions
        np.minimum(self.low, s_j, out=self.low)
        np.maximum(self.high, s_j, out=self.high)
        p_nc = self.atoms.get_momenta() + (0.5 * self.dyn.dt / s_j[0]) * \
            self.atoms.get_forces()
        p_c = p_nc.sum(axis=0)
        self.half_kinetic[self.dyn.nsteps] = 0.5 * (
            float((p_nc * p_nc / self.m_n1).sum())
            - float(p_c @ p_c) / self.total_mass)


def chain_case(system, tchain, scheme, lengths):
    atoms = system.atoms()
    n_atoms = len(atoms)
    dof = 3 * n_atoms - 3
    kT = units.kB * system.temperature_K
    h = system.timestep_fs * units.fs
    atoms.set_constraint(FixCom())  # N_f = 3N - 3: canonical at the target
    dyn = ReversibleNose(atoms, h, system.temperature_K, tdamp(system),
                         tchain=tchain, scheme=scheme)
    steps = lengths.equilibration + lengths.sampled
    start = dyn.counts
    x0_nc = atoms.get_positions()
    sampler = ChainSampler(dyn, steps)
    dyn.attach(sampler, interval=1)
    result = {'system': system.label, 'n_atoms': n_atoms, 'tchain': tchain,
              'scheme': scheme, 'timestep_fs': system.timestep_fs,
              'temperature_K': system.temperature_K}
    tic = time.perf_counter()
    try:
        dyn.run(steps)
    except Exception as error:  # what it raised is the result
        result['failure'] = f'{type(error).__name__} at step {dyn.nsteps}'
    s_range = [[float(a), float(b)] for a, b in zip(sampler.low,
                                                    sampler.high)]
    if 'failure' in result:
        print(f"  {system.label} tchain {tchain}: {result['failure']}",
              flush=True)
        return {**result, 's_range': s_range}
    seconds = time.perf_counter() - tic
    first = lengths.equilibration + 1
    edges = histogram_edges(dof, kT)
    displacement = atoms.get_positions() - x0_nc
    thermostat = nose_statistics(sampler, first, system.timestep_fs)
    half = copy.copy(sampler)
    half.kinetic = sampler.half_kinetic
    half_stats = canonical_statistics(half, first, dof, kT, edges, h)
    result.update({
        'sampling': canonical_statistics(sampler, first, dof, kT, edges, h),
        'thermostat': thermostat, 's_range': s_range,
        'mean_square_displacement_A2': float(
            np.mean(np.sum(displacement**2, axis=1))),
        'seconds': seconds,
        'half_kicked': {'temperature_K': half_stats['temperature_K'],
                        'ks': half_stats['ks']}})
    if tchain == max(CHAIN_LENGTHS):
        dyn.observers.clear()
        dyn.reverse()
        dyn.run(steps)
        result['round_trip_equal'] = {
            name: bool(np.array_equal(dyn.counts[name], start[name]))
            for name in start}
    print(f"  {system.label} tchain {tchain} {scheme}: KS p "
          f"{result['sampling']['ks']['p_value']:.3g}", flush=True)
    return result


def run(quick, scheme='velocity'):
    lengths = QUICK if quick else FULL
    cases = [chain_case(system, tchain, scheme, lengths)
             for system in SYSTEMS for tchain in CHAIN_LENGTHS]
    return {'lengths': asdict(lengths), 'tdamp_steps': TDAMP_STEPS,
            'ks_level': KS_LEVEL, 'chain_stiffness': CHAIN_STIFFNESS,
            'cases': cases}
