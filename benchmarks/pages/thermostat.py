"""ReversibleLangevin against ASE's Langevin, ReversibleBussi against ASE's
Bussi: sampling, exact reversal, information buffer, cost per step.

Measured by benchmarks/thermostat.py; the Bussi block fills
docs/thermostats.md.
"""

from __future__ import annotations

import math

import numpy as np

from . import Spec, block, figure, markdown_table, table

PLOT = 'thermostat_kinetic_energy.png'

THERMOSTATS = (('reversible_langevin', 'ReversibleLangevin'),
               ('ase_langevin', 'ASE Langevin'))
BUSSI_PLOT = 'thermostat_bussi_kinetic_energy.png'
BUSSI_THERMOSTATS = (('reversible_bussi', 'ReversibleBussi'),
                     ('ase_bussi', 'ASE Bussi'))
SPEED_COLUMNS = (('reversible_langevin', 'ReversibleLangevin'),
                 ('ase_langevin', 'ASE Langevin'),
                 ('velocity_verlet', 'ASE VelocityVerlet'),
                 ('reversible_verlet', 'ReversibleVerlet'))


def gamma_density(x, shape, scale):
    x = np.asarray(x, float)
    log = ((shape - 1) * np.log(x) - x / scale - math.lgamma(shape)
           - shape * math.log(scale))
    return np.exp(log)


def plot(results, figures):
    histograms(results['systems'], THERMOSTATS, figures / PLOT)
    if 'bussi' in results:
        histograms(results['bussi']['systems'], BUSSI_THERMOSTATS,
                   figures / BUSSI_PLOT)


def histograms(systems, thermostats, path):
    """One panel per system: each thermostat's histogram of the internal
    kinetic energy against the analytic Gamma density, saved to ``path``."""
    with figure(path, len(systems),
                (5 * len(systems), 3.8)) as (plt, fig, axes):
        for ax, s in zip(np.atleast_1d(axes), systems):
            edges = np.asarray(s['histogram_edges_eV'])
            width = np.diff(edges)
            for (key, label), color in zip(thermostats, ('C0', 'C3')):
                run = s['sampling'][key]
                density = np.asarray(run['histogram_counts']) / (
                    run['samples'] * width)
                ax.stairs(density, edges, color=color, lw=1.4,
                          label=f'{label} ({run["samples"]:,} steps)')
            x = np.linspace(edges[0], edges[-1], 400)
            ax.plot(x, gamma_density(x, s['dof'] / 2, s['kT_eV']), 'k--', lw=1,
                    label=f"Gamma({s['dof']}/2, kT)")
            ax.set_xlabel('internal kinetic energy (eV)')
            ax.set_ylabel('density (1/eV)')
            ax.set_title(f"{s['system']} {s['n_atoms']} atoms, "
                         f"{s['calculator']}, {s['temperature_K']:g} K, "
                         f"{s['timestep_fs']:g} fs", fontsize=10)
            ax.legend(fontsize=8, loc='upper right')


# -- helpers -----------------------------------------------------------------


def yes(ok):
    return 'yes' if ok else '**no**'


def deviation_percent(s, key):
    t = s['sampling'][key]['temperature_K']
    return 100 * (t['mean'] / s['temperature_K'] - 1)


def deviation_in_errors(s, key):
    t = s['sampling'][key]['temperature_K']
    return (t['mean'] - s['temperature_K']) / t['standard_error']


def bits_ratio(s, checkpoint):
    return (checkpoint['bits_per_step_per_coordinate']
            / s['buffer']['minimum_bits_per_step_per_coordinate'])


def size(n_bytes):
    for unit, scale in (('GB', 1e9), ('MB', 1e6), ('kB', 1e3)):
        if n_bytes >= scale:
            return f'{n_bytes / scale:.3g} {unit}'
    return f'{n_bytes:.0f} B'


def us(seconds):
    return f'{seconds * 1e6:.0f}'


# -- sections ----------------------------------------------------------------

def sampling_table(results, thermostats=THERMOSTATS):
    rows = []
    for s in results['systems']:
        for key, label in thermostats:
            r = s['sampling'][key]
            t, e, ks = r['temperature_K'], r['potential_energy'], r['ks']
            rows.append([
                f"{s['system']} {s['n_atoms']}", label, f"{r['samples']:,}",
                f"{t['mean']:.2f} ± {t['standard_error']:.2f}",
                f'{deviation_percent(s, key):+.2f}% '
                f'({deviation_in_errors(s, key):+.1f} SE)',
                f"{r['kinetic_correlation_time_steps']:.1f}",
                f"{ks['stride']} / {ks['samples']:,} / "
                f"{ks['lag1_of_thinned']:+.2f}",
                f"{ks['statistic']:.4f}", f"{ks['p_value']:.3g}",
                f"{ks['shape_p_value']:.3g}",
                f"{e['mean']:.3f} ± {e['standard_error']:.3f}",
                f"{e['correlation_time_steps']:.1f}",
                f"{r['max_com_kinetic_over_kT']:.1e}"])
    return markdown_table(
        ['system', 'thermostat', 'samples (steps)', 'T_kin (K)',
         'T_kin / T - 1', 'g of K (steps)',
         'KS stride / samples / lag-1 corr.', 'KS D', 'KS p',
         'KS p, scale from ⟨K⟩',
         'E_pot (eV)', 'g of E_pot (steps)', 'max K_cm / kT'], rows)


def potential_lines(results, name='ReversibleLangevin'):
    """Per system: ``name``'s mean potential energy minus ASE Langevin's,
    with the two errors added in quadrature."""
    return '\n'.join(
        f"- {s['system']} {s['n_atoms']}: {name} − ASE Langevin = "
        f"{d:+.4f} ± {se:.4f} eV ({d / se:+.1f} standard errors; "
        f"{1e3 * d / s['n_atoms']:+.3f} meV per atom)."
        for s in results['systems']
        for d, se in [(s['potential_difference_eV'],
                       s['potential_difference_standard_error_eV'])])


def offset_lines(results, key, predicted, word='predicted',
                 step=lambda s: ''):
    """Per system: the kinetic-temperature offset ``predicted(s, run)`` (%)
    against ``key``'s measured one."""
    return '\n'.join(
        f"- {s['system']} ({s['timestep_fs']:g} fs{step(s)}): ⟨ω²⟩ = "
        f"{r['mean_omega_squared_per_fs2']:.3g} / fs², {word} "
        f"{predicted(s, r):+.2f}%, measured {deviation_percent(s, key):+.2f}"
        f" ± {100 * r['temperature_K']['standard_error'] / s['temperature_K']:.2f}%."
        for s in results['systems'] for r in [s['sampling'][key]])


def system(s):
    return f"{s['system']} {s['n_atoms']}"


ROUND_TRIP_COLUMNS = (
    ('system', system), ('steps each way', '{round_trip[steps_each_way]:,}'),
    *((header, lambda s, k=k: yes(s['round_trip'][k])) for header, k in (
        ('positions equal', 'positions_equal'),
        ('momenta equal', 'momenta_equal'),
        ('integer state equal', 'state_equal'),
        ('buffer empty', 'buffer_empty'))),
    ('forward (s)', '{round_trip[forward_seconds]:.0f}'),
    ('back (s)', '{round_trip[back_seconds]:.0f}'),
    ('total (s)', lambda s: '{:.0f}'.format(
        s['round_trip']['forward_seconds'] + s['round_trip']['back_seconds'])))


def warning_lines(results, name='ReversibleLangevin'):
    out = []
    for s in results['systems']:
        for w in s['round_trip']['warnings']:
            out.append(f"- {s['system']}: `{w}`")
    return (f'Warnings {name} gave during the round trips:\n\n'
            + '\n'.join(out)) if out else \
        f'{name} gave no warning during the round trips.'


def buffer_table(results):
    """Per checkpoint (and the extrapolated point): the bits held against
    the minimum, the buffer's memory against a stored trajectory's."""
    rows = []
    for s in results['systems']:
        b = s['buffer']
        for c in b['checkpoints'] + [b['extrapolated']]:
            held = 'bits_per_step_per_coordinate' in c
            rows.append([
                f"{s['system']} {s['n_atoms']}", f"{c['steps']:,}"
                + (' (extrapolated)' if c.get('extrapolated') else ''),
                f"{c['bits_per_step_per_coordinate']:.6f}" if held else '–',
                f'{bits_ratio(s, c):.4f}' if held else '–',
                size(c['nbytes']), size(c['allocated_bytes'])
                if 'allocated_bytes' in c else '–',
                size(c['trajectory_bytes']),
                f"{c['trajectory_bytes'] / c['nbytes']:.0f}"])
    return markdown_table(
        ['system', 'steps', 'bits held / step / coordinate',
         'ratio to −log2(c)', 'buffer memory (nbytes)', 'allocated',
         'trajectory (x and p, float64)', 'trajectory / buffer'], rows)


def speed_table(results, columns=SPEED_COLUMNS, base_key='ase_langevin'):
    base_label = dict(columns)[base_key]
    rows = []
    for r in results['speed']:
        med = r['median_seconds']
        base = med[base_key]
        wall_cpu = max(med[k] / r['median_cpu_seconds'][k] for k in med)
        rows.append(
            [f"{r['calculator']} {r['system']}", r['n_atoms'],
             f"{r['steps_per_block']} × {r['rounds']}"]
            + [f'{us(med[k])} (×{med[k] / base:.2f})' for k, _ in
               columns]
            + [f"{100 * max(r['spread'].values()):.0f}%",
               f'{wall_cpu:.2f}'])
    return markdown_table(
        ['calculator, system', 'atoms', 'steps × rounds']
        + [f'{label} µs/step (× {base_label})' for _, label in columns]
        + ['round spread', 'wall / CPU'], rows)


# -- Bussi -------------------------------------------------------------------

def bussi_sampling_lines(bussi):
    """One line per system and thermostat: T_kin, KS p."""
    out = []
    for s in bussi['systems']:
        for key, label in BUSSI_THERMOSTATS:
            r = s['sampling'][key]
            t, ks = r['temperature_K'], r['ks']
            out.append(
                f"- {label}, {s['system']} {s['n_atoms']} "
                f"({s['calculator']}, {s['temperature_K']:g} K): T_kin "
                f"{t['mean']:.2f} ± {t['standard_error']:.2f} K "
                f"({deviation_in_errors(s, key):+.1f} SE), "
                f"Kolmogorov-Smirnov p = {ks['p_value']:.2g} against "
                f"Gamma({s['dof']}/2, kT) ({ks['samples']:,} samples, every "
                f"{ks['stride']}th step of {r['samples']:,}).")
    return '\n'.join(out)


BUSSI_BUFFER_COLUMNS = (
    ('system', '{system}'), ('steps', '{steps:,}'),
    ('ratio bits', '{ratio_bits:,.0f}'),
    ('coordinates: bits each', '{coordinate_bits_per_coordinate:+.2f}'),
    ('stack pointers low / high',
     '{lowest_stack_pointer} / {highest_stack_pointer}'),
    ('memory', lambda c: size(c['nbytes'])))


def bussi_buffer_table(bussi):
    return table(BUSSI_BUFFER_COLUMNS, [
        {**c, 'system': system(s)} for s in bussi['systems']
        for c in s['buffer_checkpoints']])


def bussi_round_trips(bussi):
    out = []
    for s in bussi['systems']:
        rt = s['round_trip']
        out.append(f"- {s['system']} {s['n_atoms']}: "
                   f"{rt['steps_each_way']:,} steps out and back, state "
                   'equal and buffer empty: '
                   f"{yes(rt['state_equal'] and rt['buffer_empty'])} "
                   f"({rt['forward_seconds']:.0f} s out with the sampling "
                   f"observer, {rt['back_seconds']:.0f} s back).")
    return '\n'.join(out)


def bussi_speed_table(bussi):
    return speed_table({'speed': bussi['speed']}, BUSSI_THERMOSTATS,
                       'ase_bussi')


def bussi_doc_block(stored):
    """The numbers of docs/thermostats.md's ReversibleBussi section."""
    bussi = stored['results']['bussi']
    return (f"*Measured {stored['date'][:10]} by `{stored['command']}`"
            + (' (quick mode)' if stored['quick'] else '') + '.*\n\n'
            + bussi_sampling_lines(bussi) + '\n\n'
            + bussi_round_trips(bussi) + '\n\n'
            + bussi_buffer_table(bussi) + '\n\n'
            + bussi_speed_table(bussi))


def values(results):
    """The prose's numbers: the buffer's ratio per system, the loads."""
    load = results['load_average']
    return {'ratios': '; '.join(
        f"{s['system']}: c = {s['buffer']['ratio_numerator']} / 65536 = "
        f"{s['buffer']['ratio']:.6f}, effective friction "
        f"{s['buffer']['effective_friction_per_fs']:.7f} / fs"
        for s in results['systems']),
        'systems_described': '; '.join(
        f"{s['system']} {s['n_atoms']} atoms with {s['calculator']}, "
        f"{s['temperature_K']:g} K, {s['timestep_fs']:g} fs"
        for s in results['systems']),
        'dof': results['systems'][0]['dof'],
        'load_start': load['start'][0], 'load_end': load['end'][0],
        'load_before_cost': load['before_cost'][0]}


SPEC = Spec(
    'Thermostat: ReversibleLangevin against ASE Langevin',
    blocks={'sampling': block(sampling_table),
            'baoab': lambda stored: offset_lines(
                stored['results'], 'reversible_langevin',
                lambda s, r: r['baoab_harmonic_kinetic_bias_percent']),
            'potential': block(potential_lines),
            'round-trip': lambda stored: table(
                ROUND_TRIP_COLUMNS, stored['results']['systems']),
            'warnings': block(warning_lines),
            'buffer': block(buffer_table),
            'speed': block(speed_table),
            'bussi': bussi_doc_block},
    plots=(plot,), values=values)
