"""Nosé at large time steps: which momenta the thermostat holds at T, for
ReversibleNose's schemes and ASE's NoseHooverChainNVT (``--only
nose_timestep``: ~14 minutes; stored as the nose section's 'timestep').
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import math
import time
from dataclasses import asdict

import numpy as np
from ase import units
from ase.constraints import FixCom
from ase.build import bulk
from ase.md.nose_hoover_chain import NoseHooverChainNVT
from ase.md.velocitydistribution import (MaxwellBoltzmannDistribution,
                                         Stationary)
from harness import BLOCKS, StudyLengths, block_mean
from systems import CALCULATORS

from ase_reversible import ReversibleNose

TIMESTEPS_FS = (2.0, 5.0, 10.0, 20.0)
TDAMP_STEPS = 100
SAMPLE_EVERY = 5
#: ReversibleNose's schemes (and the velocity scheme with a chain of 3),
#: and ASE's chain.
KINDS = ('velocity', 'position', 'velocity-tchain3', 'ase_nose_hoover_chain')


FULL = StudyLengths(equilibration=5000, sampled=40_000)
QUICK = StudyLengths(equilibration=200, sampled=1000)


def gold_256():
    atoms = bulk('Au', 'fcc', a=4.08, cubic=True).repeat((4, 4, 4))
    MaxwellBoltzmannDistribution(atoms, temperature_K=600,
                                 rng=np.random.default_rng(1))
    Stationary(atoms)
    atoms.calc = CALCULATORS['asap3 EMT']()
    return atoms


class StepSampler:
    """Observer: the on-step kinetic temperature, that of the half-kicked
    momenta ``(p' + h F / 2) / s`` (what the velocity scheme's thermostat
    reads), and the potential energy."""

    def __init__(self, dyn, dof):
        self.dyn, self.atoms = dyn, dyn.atoms
        self.m_n1 = self.atoms.get_masses()[:, None]
        self.scale = 1.0 / (dof * units.kB)
        self.on, self.half, self.potential = [], [], []

    def __call__(self):
        p_nc = self.atoms.get_momenta()
        self.on.append(float((p_nc * p_nc / self.m_n1).sum()) * self.scale)
        s = getattr(self.dyn, 'thermostat_position', None)
        if s is not None:
            f_nc = self.atoms.get_forces()
            h_nc = p_nc + (0.5 * self.dyn.dt / s) * f_nc
            self.half.append(float((h_nc * h_nc / self.m_n1).sum())
                             * self.scale)
        self.potential.append(self.atoms.get_potential_energy())


def timestep_case(kind, dt_fs, lengths):
    """One run: ``kind`` is a ReversibleNose scheme or
    ``'ase_nose_hoover_chain'``."""
    atoms = gold_256()
    dof = 3 * len(atoms) - 3
    dt = dt_fs * units.fs
    if kind == 'ase_nose_hoover_chain':
        dyn = NoseHooverChainNVT(atoms, dt, temperature_K=300,
                                 tdamp=TDAMP_STEPS * dt)
    else:
        scheme, _, chain = kind.partition('-tchain')
        atoms.set_constraint(FixCom())  # N_f = 3N - 3, as dof above
        dyn = ReversibleNose(atoms, dt, temperature_K=300,
                             tdamp=TDAMP_STEPS * dt, scheme=scheme,
                             tchain=int(chain or 1))
    tic = time.perf_counter()
    dyn.run(lengths.equilibration)
    sampler = StepSampler(dyn, dof)
    dyn.attach(sampler, interval=SAMPLE_EVERY)
    dyn.run(lengths.sampled)
    potential = np.array(sampler.potential[1:])
    result = {'kind': kind, 'timestep_fs': dt_fs,
              'seconds': time.perf_counter() - tic,
              'samples': len(potential),
              'temperature_K': block_mean(sampler.on[1:]),
              'potential_energy_eV': block_mean(potential),
              'potential_std_eV': float(potential.std())}
    if sampler.half:
        result['half_kick_temperature_K'] = block_mean(sampler.half[1:])
    if hasattr(dyn, 'thermostat_position'):
        result['s_last'] = dyn.thermostat_position
    half = result.get('half_kick_temperature_K', {}).get('mean', math.nan)
    print(f"  {kind:22s} {dt_fs:4g} fs  T {result['temperature_K']['mean']:.2f}"
          f' K (half kick {half:.2f})', flush=True)
    return result


def run(quick):
    lengths = QUICK if quick else FULL
    steps = TIMESTEPS_FS[::3] if quick else TIMESTEPS_FS
    return {'system': 'Au 256, asap3 EMT, momenta drawn at 600 K',
            'temperature_K': 300.0, 'tdamp_steps': TDAMP_STEPS,
            'sample_every': SAMPLE_EVERY, 'lengths': asdict(lengths),
            'blocks': BLOCKS,
            'cases': [timestep_case(kind, dt_fs, lengths)
                      for dt_fs in steps for kind in KINDS]}
