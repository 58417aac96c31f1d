"""ReversibleLangevin against ASE's Langevin, ReversibleBussi against ASE's
Bussi: sampling, exact reversal, information buffer, cost per step
(``--only thermostat``: ~9 minutes, ~15 s with ``--quick``).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import math
import os
from dataclasses import asdict, dataclass

import numpy as np
from ase import units
from ase.constraints import FixCom
from ase.md.bussi import Bussi
from harness import (BLOCKS, FORCE_EVERY, WINDOW_C, KineticSampler, against_reference,
                     speed_case, there_and_back)
from systems import (FRICTION_PER_FS, SEED, THERMOSTAT_SPEED,
                     THERMOSTAT_SYSTEMS, THERMOSTATS, ThermostatSystem)

from ase_reversible import ReversibleBussi
from ase_reversible.app.systems import argon_bulk
from ase_reversible.core.infobuffer import DIGIT_BITS, friction_ratio

#: The goals the page judges against.
TEMPERATURE_GOAL_PERCENT = 1.0
BITS_GOAL_RATIO = 1.1
#: Time constant of both Bussi thermostats, fs.
TAUT_FS = 100.0


@dataclass(frozen=True)
class Lengths:
    equilibration: int
    round_trip: int  # forward steps, equilibration included
    checkpoints: tuple  # forward steps at which the buffer is measured


FULL = Lengths(equilibration=2000, round_trip=100_000,
               checkpoints=(1000, 10_000, 100_000))
QUICK = Lengths(equilibration=200, round_trip=1000, checkpoints=(100, 1000))
#: Steps the memory is extrapolated to.
EXTRAPOLATE_TO = 1_000_000
#: 8 bytes each for a position and a momentum per coordinate and step.
TRAJECTORY_BYTES_PER_COORDINATE = 16

SYSTEMS = THERMOSTAT_SYSTEMS
#: (system, repeat) of the cost cases: Cu 500 and 4000, Ar 500 atoms.
SPEED_CASES = ((SYSTEMS[1], (5, 5, 5)), (SYSTEMS[1], (10, 10, 10)),
               (SYSTEMS[0], (5, 5, 5)))
SPEED_CONTESTANTS = ('reversible_langevin', 'ase_langevin', 'velocity_verlet',
                     'reversible_verlet')


def reversible_bussi(atoms, system):
    atoms.set_constraint(FixCom())
    return ReversibleBussi(atoms, system.timestep_fs * units.fs,
                           system.temperature_K, TAUT_FS * units.fs,
                           seed=SEED, force_noise=system.force_noise)


def ase_bussi(atoms, system):
    atoms.set_constraint(FixCom())
    return Bussi(atoms, system.timestep_fs * units.fs, system.temperature_K,
                 TAUT_FS * units.fs, rng=np.random.default_rng(SEED))


INTEGRATORS = {**THERMOSTATS, 'reversible_bussi': reversible_bussi,
               'ase_bussi': ase_bussi}


def buffer_sizes(dyn, steps):
    """ReversibleLangevin's information buffer after ``steps`` steps."""
    buffers = dyn.friction_step.buffers.values()
    coordinates = 3 * len(dyn.atoms)
    bits = dyn.buffer_bits
    return {'steps': steps, 'bits': bits,
            'bits_per_step_per_coordinate': bits / (steps * coordinates),
            'nbytes': sum(b.nbytes for b in buffers),
            'allocated_bytes': sum(b.state_k.nbytes + b.top_k.nbytes
                                   + b.words_jk.nbytes for b in buffers),
            'trajectory_bytes': TRAJECTORY_BYTES_PER_COORDINATE
            * coordinates * steps}


def extrapolated(checkpoints, steps=EXTRAPOLATE_TO):
    """Linear through the last two checkpoints, at ``steps`` (not the
    allocated bytes: the stacks grow by doubling)."""
    a, b = checkpoints[-2], checkpoints[-1]
    out = {'steps': steps, 'extrapolated': True}
    for key in ('nbytes', 'trajectory_bytes'):
        slope = (b[key] - a[key]) / (b['steps'] - a['steps'])
        out[key] = b[key] + slope * (steps - b['steps'])
    return out


def sampled_round_trip(system, lengths, name, reference, buffer_at,
                       buffers_of, keys=()):
    """Integrator ``name`` there and back (``buffer_at(dyn, step)`` at the
    checkpoints) against ASE's ``reference``: ``(dyn, trip, result)``, the
    result holding the round trip (the integer state and ``buffers_of(dyn)``
    back at the start, times, warnings, and ``trip``'s ``keys``)."""
    atoms = system.atoms()
    dyn, sampler, trip = there_and_back(
        lambda: INTEGRATORS[name](atoms, system), KineticSampler,
        lengths.round_trip, lengths.checkpoints, buffer_at,
        snapshot=lambda dyn: dyn.state)
    result = against_reference(
        system, lengths.equilibration + 1, (name, sampler), reference,
        INTEGRATORS[reference], lengths.round_trip)
    start, end, buffers = trip['start'], dyn.state, buffers_of(dyn)
    result.update(equilibration_steps=lengths.equilibration, round_trip={
        'steps_each_way': lengths.round_trip, 'moved': trip['moved'],
        'state_equal': bool(np.array_equal(start.ix_nc, end.ix_nc)
                            and np.array_equal(start.ip_nc, end.ip_nc)),
        'buffer_empty': bool(buffers) and all(b.is_empty() for b in buffers),
        **{k: trip[k] for k in (*keys, 'forward_seconds', 'back_seconds',
                                'warnings')}})
    return dyn, trip, result


def sampling_system(system, lengths):
    """ReversibleLangevin there and back against ASE's Langevin."""
    dyn, trip, result = sampled_round_trip(
        system, lengths, 'reversible_langevin', 'ase_langevin', buffer_sizes,
        lambda dyn: list(dyn.friction_step.buffers.values()),
        ('positions_equal', 'momenta_equal'))
    checkpoints = trip['checkpoints']
    n = friction_ratio(math.exp(-FRICTION_PER_FS * system.timestep_fs))
    return {**result,
            'buffer': {'ratio_numerator': n, 'ratio': n / 2**DIGIT_BITS,
                       'minimum_bits_per_step_per_coordinate':
                           -math.log2(n / 2**DIGIT_BITS),
                       'effective_friction_per_fs':
                           dyn.effective_friction * units.fs,
                       'checkpoints': checkpoints,
                       'extrapolated': extrapolated(checkpoints)}}


# -- Bussi --------------------------------------------------------------------

def liquid_argon(repeat, temperature_K):
    """fcc argon expanded by 1.10 (1.37 g/cm3), momenta drawn at 600 K: it
    melts as a thermostat cools it."""
    atoms = argon_bulk(repeat, 600.0)
    atoms.set_cell(atoms.cell * 1.10, scale_atoms=True)
    return atoms


#: Liquid argon (asap3 LennardJones needs a force-noise bound above the
#: default at this density: 4e-15 eV/Å was seen against 3.6e-15) and the
#: copper crystal.
BUSSI_SYSTEMS = (
    ThermostatSystem('Ar liquid', 'asap3 LJ', liquid_argon, (4, 4, 4), 90.0,
                     10.0, force_noise=1e-13),
    SYSTEMS[1],
)


BUSSI_FULL = Lengths(equilibration=1000, round_trip=21_000,
                     checkpoints=(1000, 5000, 21_000))
BUSSI_QUICK = Lengths(equilibration=200, round_trip=1000,
                      checkpoints=(200, 1000))
BUSSI_SPEED_CASES = SPEED_CASES[:2]
#: ReversibleLangevin and VelocityVerlet on these cases are in run()'s table.
BUSSI_SPEED_CONTESTANTS = ('reversible_bussi', 'ase_bussi')


def bussi_buffer(dyn, steps):
    (b,) = dyn.rescale_step.buffers.values()
    ratio_bits = 32.0 * b.count
    coordinate_bits = dyn.buffer_bits - ratio_bits
    return {'steps': steps, 'bits': dyn.buffer_bits, 'ratio_bits': ratio_bits,
            'coordinate_bits': coordinate_bits,
            'coordinate_bits_per_coordinate':
                coordinate_bits / (3 * len(dyn.atoms)),
            'lowest_stack_pointer': int(b.top_k.min()),
            'highest_stack_pointer': int(b.top_k.max()),
            'nbytes': b.nbytes}


def bussi_system(system, lengths):
    """Both Bussi thermostats on ``system``; ours then runs back."""
    _, trip, result = sampled_round_trip(
        system, lengths, 'reversible_bussi', 'ase_bussi', bussi_buffer,
        lambda dyn: list(dyn.rescale_step.buffers.values()))
    return {**result, 'taut_fs': TAUT_FS,
            'buffer_checkpoints': trip['checkpoints']}


def run_bussi(quick):
    lengths = BUSSI_QUICK if quick else BUSSI_FULL
    speed = THERMOSTAT_SPEED[quick]
    cases = BUSSI_SPEED_CASES[:1] if quick else BUSSI_SPEED_CASES
    return {'lengths': {'equilibration': lengths.equilibration,
                        'steps': lengths.round_trip}, 'taut_fs': TAUT_FS,
            'systems': [bussi_system(s, lengths) for s in BUSSI_SYSTEMS],
            'speed': [speed_case(s, r, speed, BUSSI_SPEED_CONTESTANTS,
                                 INTEGRATORS, 'ase_bussi') for s, r in cases]}


def run(quick):
    lengths = QUICK if quick else FULL
    speed = THERMOSTAT_SPEED[quick]
    # The machine is shared: the load around each part goes with it.
    load = {'start': os.getloadavg()}
    systems_ = [sampling_system(s, lengths) for s in SYSTEMS]
    load['before_cost'] = os.getloadavg()
    costs = [speed_case(s, r, speed, SPEED_CONTESTANTS, INTEGRATORS,
                        'ase_langevin')
             for s, r in (SPEED_CASES[::2] if quick else SPEED_CASES)]
    load['before_bussi'] = os.getloadavg()
    bussi = run_bussi(quick)
    load['end'] = os.getloadavg()
    return {
        'load_average': load,
        'settings': {'friction_per_fs': FRICTION_PER_FS, 'seed': SEED,
                     'blocks': BLOCKS, 'window_c': WINDOW_C,
                     'force_every': FORCE_EVERY,
                     'temperature_goal_percent': TEMPERATURE_GOAL_PERCENT,
                     'bits_goal_ratio': BITS_GOAL_RATIO,
                     'lengths_equilibration': lengths.equilibration,
                     'lengths_round_trip': lengths.round_trip,
                     'speed': asdict(speed)},
        'systems': systems_, 'speed': costs, 'bussi': bussi}
