"""Rigid TIP3P water against ASE's RATTLE.

Measured by benchmarks/rigid.py.
"""

from __future__ import annotations

from . import Spec, block, markdown_table

NAMES = (('ase', "ASE VelocityVerlet + FixBondLengths"),
         ('exact', 'ReversibleVerlet, rigid bodies'))


def energy_table(results):
    rows = [[c['n_waters'], f"{c['timestep_fs']:g}", c['steps']]
            + [f"{c[key]['std']:.2e}" for key, _ in NAMES]
            + [f"{c[key]['drift_per_ps']:+.1e}" for key, _ in NAMES]
            for c in results['energy']]
    return markdown_table(
        ['waters', 'dt (fs)', 'steps']
        + [f'{label}: std (eV/molecule)' for _, label in NAMES]
        + [f'{label}: drift (eV/molecule/ps)' for _, label in NAMES], rows)


def cost_table(results):
    rows = [[c['n_waters'], f"{c['timestep_fs']:g}",
             f"{c['seconds']['ase'] * 1e3:,.0f}",
             f"{c['seconds']['exact'] * 1e3:.1f}", f"{c['ratio']:.4f}"]
            for c in results['cost']]
    return markdown_table(
        ['waters', 'dt (fs)', 'ASE (ms/step)', 'exact (ms/step)',
         'exact / ASE'], rows)


def long_table(results):
    rows = [[c['n_waters'], f"{c['timestep_fs']:g}", f"{c['steps']:,}",
             'yes' if c['exact'] else '**no**', f"{c['bond_error']:.1e}",
             f"{c['quaternion_length_error']:.1e}", f"{c['seconds']:.0f}"]
            for c in results['long']]
    return markdown_table(
        ['waters', 'dt (fs)', 'steps each way', 'back bit for bit',
         'largest O-H or H-H error (Å)', 'largest ||q| - 1|',
         'wall time (s)'], rows)


def sampling_table(results):
    if 'sampling' not in results:
        return ('*Not measured yet: `python benchmarks/run_all.py --only '
                'rigid_sampling`.*')
    sampling = results['sampling']
    rows = [[c['thermostat'], c['n_waters'], c['degrees_of_freedom'],
             f"{c['steps']:,}",
             f"{c['temperature']:.1f} ± {c['temperature_error']:.1f}",
             f"{c['relative_deviation']:+.2%}",
             f"{c['ks_translational']:.2g}", f"{c['ks_rotational']:.2g}"]
            for c in sampling['cases']]
    trips = markdown_table(
        ['thermostat', 'waters', 'dt (fs)', 'steps each way',
         'back bit for bit', 'temperature at the turn (K)',
         'wall time (s)'],
        [[c['thermostat'], c['n_waters'], f"{c['timestep_fs']:g}",
          f"{c['steps']:,}", 'yes' if c['exact'] else '**no**',
          f"{c['temperature_at_turn']:.0f}", f"{c['seconds']:.0f}"]
         for c in sampling['round_trips']])
    return trips + '\n\n' + markdown_table(
        ['thermostat', 'waters', 'degrees of freedom', 'steps',
         'mean temperature (K)', 'from the target',
         'KS p, translational', 'KS p, rotational'], rows)


def stability_table(results):
    if 'stability' not in results:
        return ('*Not measured yet: `python benchmarks/run_all.py --only '
                'rigid_stability`.*')
    rows = [[f"{c['timestep_fs']:g}", c['n_waters'], f"{c['steps']:,}",
             'no' if c['stopped_at'] is None
             else f"at step {c['stopped_at']}",
             f"{c['energy_change_per_molecule']:+.1e}"]
            for c in results['stability']['cases']]
    return markdown_table(
        ['dt (fs)', 'waters', 'steps', 'stopped by the energy check',
         'energy change (eV/molecule)'], rows)


SPEC = Spec('Rigid water against RATTLE', blocks={
    'energy': block(energy_table), 'cost': block(cost_table),
    'long': block(long_table), 'sampling': block(sampling_table),
    'stability': block(stability_table)})
