"""ReversibleNose against ASE's thermostats: sampling, exact reversal,
cost per step.

Measured by benchmarks/nose.py and benchmarks/studies/nose_timestep.py,
nose_chain.py.
"""

from __future__ import annotations

from . import Spec, markdown_table, table, thermostat
from .thermostat import (histograms, offset_lines, potential_lines,
                         sampling_table, speed_table, system, warning_lines,
                         yes)

PLOT = 'nose_kinetic_energy.png'

NOSE = ('reversible_nose', 'ReversibleNose')
#: ReversibleNose in place of ReversibleLangevin, beside ASE's Langevin.
THERMOSTATS = (NOSE, *thermostat.THERMOSTATS[1:])
SPEED_COLUMNS = (NOSE, ('ase_nose_hoover_chain', 'ASE NoseHooverChainNVT'))
COUNTS = ('position', 'momentum', 'thermostat_position',
          'thermostat_momentum', 'time')


def plot(results, figures):
    histograms(results['systems'], THERMOSTATS, figures / PLOT)


# -- tables ------------------------------------------------------------------

def meV_per_atom(s, energy, sign=''):
    return f"{1e3 * energy / s['n_atoms']:{sign}.3f}"


THERMOSTAT_COLUMNS = (
    ('system', system),
    ('s (mean ± SE)',
     '{thermostat[s][mean]:.4f} ± {thermostat[s][standard_error]:.4f}'),
    ('s std', '{thermostat[s][std]:.4f}'),
    ('s range, sampled',
     '{thermostat[s][min]:.3f} – {thermostat[s][max]:.3f}'),
    ('s range, from the start', '{thermostat[s_from_start][min]:.3f} – '
                                '{thermostat[s_from_start][max]:.3f}'),
    ('g of s (steps)', '{thermostat[s][correlation_time_steps]:.0f}'),
    ('real step dt / s (fs): mean (range)',
     '{thermostat[real_timestep_fs][mean]:.3f} '
     '({thermostat[real_timestep_fs][min]:.3f} – '
     '{thermostat[real_timestep_fs][max]:.3f})'),
    ('real time / (steps × dt)', lambda s: '{:.4f}'.format(
        s['round_trip']['real_time_forward_fs']
        / (s['round_trip']['steps_each_way'] * s['timestep_fs']))),
    ('extended energy: max |E − E₀| (meV/atom)', lambda s: meV_per_atom(
        s, s['thermostat']['extended_energy_eV']['max_deviation'])),
    ('last − first (meV/atom)', lambda s: meV_per_atom(
        s, s['thermostat']['extended_energy_eV']['last']
        - s['thermostat']['extended_energy_eV']['first'], '+')))


def equal(flags, key):
    return yes(flags[key]) if key in flags else '–'


ROUND_TRIP_COLUMNS = (
    ('system', system), ('steps each way', '{round_trip[steps_each_way]:,}'),
    *((f'counts `{k}` equal',
       lambda s, k=k: equal(s['round_trip']['counts_equal'], k))
      for k in COUNTS),
    ('atoms: positions equal', lambda s: equal(s['round_trip'],
                                               'positions_equal')),
    ('atoms: momenta equal', lambda s: equal(s['round_trip'],
                                             'momenta_equal')),
    ('get_time() after (fs)', '{round_trip[time_after_fs]:g}'),
    ('forward (s)', '{round_trip[forward_seconds]:.0f}'),
    ('back (s)', '{round_trip[back_seconds]:.0f}'),
    ('total (s)', lambda s: '{:.0f}'.format(
        s['round_trip']['forward_seconds'] + s['round_trip']['back_seconds'])))


# -- the studies (benchmarks/studies/nose_timestep.py, nose_chain.py) -------

def _mean_se(block, digits=2):
    return f"{block['mean']:.{digits}f} ± {block['standard_error']:.{digits}f}"


def _study_line(study):
    load = study['load_average']
    return (f"*Measured {study['date']} by `{study['command']}` in "
            f"{study['wall_seconds']:.0f} s, commit {study['git_commit']}, "
            f"load average {load['start'][0]:.1f} at the start and "
            f"{load['end'][0]:.1f} at the end (2 cores shared with other "
            'jobs).*')


def timestep_block(stored):
    """docs/thermostats.md, "Large time steps": the measured table."""
    study = stored['results'].get('timestep')
    if study is None:
        return ('Not measured yet: `python benchmarks/run_all.py --only '
                'nose_timestep`.')
    cases = study['cases']
    by = {(c['kind'], c['timestep_fs']): c for c in cases}
    steps = sorted({c['timestep_fs'] for c in cases})
    kinds = (('velocity', "scheme='velocity'"),
             ('position', "scheme='position'"),
             ('velocity-tchain3', "scheme='velocity', tchain=3"),
             ('ase_nose_hoover_chain', 'ASE NoseHooverChainNVT'))
    kinds = tuple(k for k in kinds if (k[0], steps[0]) in by)
    reference = {k: by[(k, steps[0])]['potential_energy_eV']['mean']
                 for k, _ in kinds}
    rows = []
    for dt in steps:
        for kind, label in kinds:
            c = by.get((kind, dt))
            if c is None:
                continue
            u = c['potential_energy_eV']
            half = (c.get('half_kick_temperature_K')
                    if kind.startswith('velocity') else None)
            du = u['mean'] - reference[kind]
            rows.append([
                f'{dt:g}', label, _mean_se(c['temperature_K']),
                _mean_se(half) if half else '',
                f"{u['mean']:.3f} ± {u['standard_error']:.3f}",
                f'{du:+.3f}' if dt != steps[0] else '(reference)',
                f"{c['potential_std_eV']:.3f}"])
    return f"""\
{markdown_table(['dt (fs)', 'integrator', 'T on-step (K)',
                 'T half kicked (K)', '⟨U⟩ (eV)', '⟨U⟩ − ⟨U⟩(2 fs) (eV)',
                 'std U (eV)'], rows)}

{_study_line(study)}
"""


def chain_block(stored):
    """docs/thermostats.md, "A chain of thermostats": the measured table."""
    study = stored['results'].get('chain')
    if study is None:
        return ('Not measured yet: `python benchmarks/run_all.py --only '
                'nose_chain`.')
    rows = []
    for c in study['cases']:
        head = [f"{c['system']} {c['n_atoms']}, {c['temperature_K']:g} K, "
                f"{c['timestep_fs']:g} fs", c['tchain']]
        s_ranges = ', '.join(f'{a:.2f}–{b:.2f}' for a, b in c['s_range'])
        if c.get('failure'):
            rows.append(head + [c['failure'], '', '', '', '', s_ranges, '', ''])
            continue
        ks = c['sampling']['ks']
        e = c['thermostat']['extended_energy_eV']
        exact = c.get('round_trip_equal')
        rows.append(head + [
            _mean_se(c['sampling']['temperature_K']),
            f"{ks['p_value']:.2g}", f"{ks['shape_p_value']:.2g}",
            f"{c['half_kicked']['ks']['p_value']:.2g}",
            f"{e['std']:.2g} / {e['max_deviation']:.2g}", s_ranges,
            f"{c['mean_square_displacement_A2']:.2g}",
            '' if exact is None else yes(all(exact.values()))])
    return f"""\
{markdown_table(['system', 'tchain', 'T (K)', 'KS p', 'KS p (shape)',
                 'KS p (half kicked)', 'H std / max change (eV)',
                 's_1 … s_M range', 'MSD (Å²)', 'back bit for bit'], rows)}

{_study_line(study)}
"""


def values(results):
    """The prose's numbers: the systems, the loads, the chain's scheme."""
    load, first = results['load_average'], results['systems'][0]
    out = {'systems_described': '; '.join(
        f"{s['system']} {s['n_atoms']} atoms with {s['calculator']}, "
        f"{s['temperature_K']:g} K, {s['timestep_fs']:g} fs, tdamp "
        f"{s['thermostat']['tdamp_fs']:g} fs" for s in results['systems']),
        'n_f': first['thermostat']['degrees_of_freedom'],
        'n_atoms': first['n_atoms'], 'dof': first['dof'],
        'load_start': load['start'][0], 'load_end': load['end'][0],
        'load_before_cost': load['before_cost'][0]}
    if 'chain' in results:
        out['chain_scheme'] = results['chain']['cases'][0]['scheme']
    return out


SPEC = Spec(
    "Nosé thermostat: ReversibleNose against ASE's thermostats",
    blocks={'sampling': lambda stored: sampling_table(stored['results'],
                                                      THERMOSTATS),
            'thermostat': lambda stored: table(
                THERMOSTAT_COLUMNS, stored['results']['systems']),
            'harmonic': lambda stored: offset_lines(
                stored['results'], 'reversible_nose',
                lambda s, r: s['thermostat']['harmonic_kinetic_offset_percent'],
                'estimate', lambda s: ', rms real step '
                f"{s['thermostat']['real_timestep_fs']['rms']:.3f} fs"),
            'potential': lambda stored: potential_lines(stored['results'],
                                                        'ReversibleNose'),
            'round-trip': lambda stored: table(
                ROUND_TRIP_COLUMNS, stored['results']['systems']),
            'warnings': lambda stored: warning_lines(stored['results'],
                                                     'ReversibleNose'),
            'speed': lambda stored: speed_table(
                stored['results'], SPEED_COLUMNS, 'ase_nose_hoover_chain'),
            'timestep': timestep_block,
            'chain': chain_block},
    plots=(plot,), values=values)
