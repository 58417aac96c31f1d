"""ReversibleIsotropicNPT against ASE's IsotropicMTKNPT: volume,
compressibility, temperature, and the reversible run's round trip.

Measured by benchmarks/studies/npt_sampling.py, whose docstring gives the
method.
"""

from __future__ import annotations

from . import Spec, block, markdown_table


INTEGRATORS = (('reversible_npt', 'ReversibleIsotropicNPT'),
               ('ase_npt', 'ASE IsotropicMTKNPT'))


def deviation_percent(case, run):
    return 100 * (run['temperature_K']['mean'] / case['temperature_K'] - 1)


def yes(ok):
    return 'yes' if ok else '**no**'


def sampling_table(results):
    rows = []
    for c in results['cases']:
        for key, label in INTEGRATORS:
            r = c['runs'][key]
            v, k, t = r['volume_A3'], r['compressibility'], r['temperature_K']
            dev = deviation_percent(c, r)
            rows.append([
                c['label'], label, f"{r['samples']:,}",
                f"{v['mean']:.1f} ± {v['standard_error']:.1f}",
                f"{v['correlation_time_steps']:.0f} "
                f"({v['block_length_over_correlation_time']:.1f})",
                f"{k['per_GPa']:.4g} ± {k['standard_error_per_GPa']:.2g} "
                f"(± {k['standard_error_from_g_per_GPa']:.2g}, "
                f"g {k['square_correlation_time_steps']:.0f})",
                f"{t['mean']:.2f} ± {t['standard_error']:.2f} "
                f"({dev:+.2f}%)",
                f"{r['msd_A2']['half']:.3g} / {r['msd_A2']['end']:.3g}",
                f"{r['forward_seconds']:.0f}"])
    return markdown_table(
        ['case', 'integrator', 'samples (steps)', '⟨V⟩ (Å³)',
         'g of V in steps (block length / g)',
         'κ_T (1/GPa) ± jackknife (± from g of (V − ⟨V⟩)², that g)',
         '⟨T⟩ (K) (off target)',
         'MSD at half / end (Å²)', 'forward wall time (s)'], rows)


def difference_table(results):
    rows = []
    for c in results['cases']:
        d = c['difference']

        def cell(x, digits):
            return (f"{x['difference']:+.{digits}g} ± "
                    f"{x['combined_error']:.2g} "
                    f"({x['in_errors']:+.1f} σ)")
        u = d.get('potential_energy')
        rows.append([c['label'], cell(d['volume'], 3),
                     cell(d['compressibility'], 2),
                     cell(d['temperature'], 2),
                     '—' if u is None else cell(u, 2)])
    return markdown_table(['case', 'Δ⟨V⟩ (Å³)', 'Δκ_T (1/GPa)', 'Δ⟨T⟩ (K)',
                           'Δ⟨E_pot⟩ (eV)'], rows)


def round_trip_table(results):
    rows = []
    for c in results['cases']:
        rt = c['runs'].get('reversible_npt', {}).get('round_trip')
        if rt is None:
            continue
        unequal = [k for k, ok in rt['equal'].items() if not ok]
        rows.append([
            c['label'], f"{rt['steps_each_way']:,}",
            yes(rt['moved'] and rt['cell_moved']),
            f"{len(rt['equal'])}: " + (', '.join(sorted(rt['equal']))),
            'all' if not unequal else '**not: ' + ', '.join(unequal) + '**',
            '—' if not rt['buffer_bits_at_turn']
            else f"{rt['buffer_bits_at_turn']:,} / {rt['buffer_bits_after']:,}",
            f"{c['runs']['reversible_npt']['forward_seconds']:.0f} / "
            f"{rt['back_seconds']:.0f}"])
    return markdown_table(
        ['case', 'steps each way', 'atoms and cell moved',
         'compared with np.array_equal', 'equal at the end',
         'buffer bits at the turn / after', 'wall time out / back (s)'],
        rows)


def warnings_seen(results):
    lines = [f"- {c['label']}, {label}: {w}"
             for c in results['cases'] for key, label in INTEGRATORS
             for w in c['runs'].get(key, {}).get('warnings', [])]
    return ('Warnings raised during the runs:\n\n' + '\n'.join(lines)
            if lines else 'No warnings were raised during the runs.')


SPEC = Spec(
    'Constant pressure: ReversibleIsotropicNPT against ASE IsotropicMTKNPT',
    blocks={'sampling': block(sampling_table),
            'difference': block(difference_table),
            'round-trip': block(round_trip_table),
            'warnings': block(warnings_seen)})
