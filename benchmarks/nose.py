"""ReversibleNose against ASE's thermostats: sampling, exact reversal,
cost per step (``--only nose``: 12-15 minutes, ~15 s with ``--quick``).
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import os
from dataclasses import asdict
from types import SimpleNamespace

import numpy as np
from ase import units
from harness import (BLOCKS, FORCE_EVERY, WINDOW_C, NoseSampler,
                     against_reference, nose_statistics, speed_case,
                     there_and_back)
from systems import (FRICTION_PER_FS, NOSE_SYSTEMS, SEED, START_FACTOR,
                     TDAMP_STEPS, THERMOSTAT_SPEED, THERMOSTATS, ase_langevin,
                     reversible_nose)


#: The goals the page judges against.
TEMPERATURE_GOAL_PERCENT = 1.0
KS_LEVEL = 0.01
POTENTIAL_GOAL_SE = 2.0
COST_GOAL_RATIO = 1.05

SYSTEMS = NOSE_SYSTEMS


#: Steps of equilibration, and forward steps (equilibration included).
FULL = SimpleNamespace(equilibration=2000, round_trip=100_000)
QUICK = SimpleNamespace(equilibration=200, round_trip=1000)
#: Copper, asap3 EMT: 1000 and 4000 atoms.
SPEED_CASES = ((SYSTEMS[1], (5, 5, 10)), (SYSTEMS[1], (10, 10, 10)))
#: ASE Langevin, VelocityVerlet and ReversibleVerlet on Cu 4000 at 5 fs, and
#: a repeated get_forces(), are in the thermostat section's cost table.
SPEED_CONTESTANTS = ('reversible_nose', 'ase_nose_hoover_chain')


def sampling_system(system, lengths):
    """ReversibleNose there and back against ASE's Langevin."""
    atoms = system.atoms()
    dyn, ours, trip = there_and_back(
        lambda: reversible_nose(atoms, system), NoseSampler,
        lengths.round_trip, at_turn=lambda dyn: {
            'real_time_forward_fs': dyn.get_time() / units.fs},
        snapshot=lambda dyn: dyn.counts)
    start, end = trip['start'], dyn.counts
    round_trip = {
        'steps_each_way': lengths.round_trip, 'moved': trip['moved'],
        'counts_equal': {name: bool(np.array_equal(end[name], start[name]))
                         for name in start},
        **{k: trip[k] for k in ('positions_equal', 'momenta_equal')},
        'time_after_fs': dyn.get_time() / units.fs,
        **{k: trip[k] for k in ('real_time_forward_fs', 'forward_seconds',
                                'back_seconds', 'warnings')}}
    first = lengths.equilibration + 1
    result = against_reference(system, first, ('reversible_nose', ours),
                               'ase_langevin', ase_langevin,
                               lengths.round_trip)
    thermostat = {'degrees_of_freedom': dyn.degrees_of_freedom,
                  'tdamp_fs': dyn.tdamp / units.fs,
                  **nose_statistics(ours, first, system.timestep_fs)}
    # The pi kicks read the momenta between the two half kicks, so those
    # are what the thermostat steers to T; for a harmonic mode the momenta
    # at the step's end are then cooler by (h omega)**2 / 4, h = dt / s.
    thermostat['harmonic_kinetic_offset_percent'] = (
        -100 * thermostat['real_timestep_fs']['rms']**2
        * result['sampling']['reversible_nose']['mean_omega_squared_per_fs2']
        / 4)
    return {**result, 'equilibration_steps': lengths.equilibration,
            'thermostat': thermostat, 'round_trip': round_trip}


def run(quick):
    lengths, speed = (QUICK if quick else FULL), THERMOSTAT_SPEED[quick]
    # The machine is shared: the load around each part goes with it.
    load = {'start': os.getloadavg()}
    systems_ = [sampling_system(s, lengths) for s in SYSTEMS]
    load['before_cost'] = os.getloadavg()
    costs = [speed_case(s, r, speed, SPEED_CONTESTANTS, THERMOSTATS,
                        'ase_nose_hoover_chain')
             for s, r in (SPEED_CASES[:1] if quick else SPEED_CASES)]
    load['end'] = os.getloadavg()
    return {
        'load_average': load,
        'settings': {'start_factor': START_FACTOR,
                     'tdamp_steps': TDAMP_STEPS,
                     'langevin_friction_per_fs': FRICTION_PER_FS,
                     'langevin_seed': SEED,
                     'blocks': BLOCKS, 'window_c': WINDOW_C,
                     'force_every': FORCE_EVERY,
                     'temperature_goal_percent': TEMPERATURE_GOAL_PERCENT,
                     'ks_level': KS_LEVEL,
                     'potential_goal_standard_errors': POTENTIAL_GOAL_SE,
                     'cost_goal_ratio': COST_GOAL_RATIO,
                     'lengths_equilibration': lengths.equilibration,
                     'lengths_round_trip': lengths.round_trip,
                     'speed': asdict(speed)},
        'systems': systems_, 'speed': costs}
