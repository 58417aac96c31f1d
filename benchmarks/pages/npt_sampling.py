"""ReversibleIsotropicNPT against ASE's IsotropicMTKNPT: volume,
compressibility, temperature, and the reversible run's round trip.

Measured by benchmarks/npt_sampling.py, whose docstring gives the method.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'Constant pressure: ReversibleIsotropicNPT against ASE IsotropicMTKNPT'

INTEGRATORS = (('reversible_npt', 'ReversibleIsotropicNPT'),
               ('ase_npt', 'ASE IsotropicMTKNPT'))


def plot(results, figures):
    """No plot: tables."""


def deviation_percent(case, run):
    return 100 * (run['temperature_K']['mean'] / case['temperature_K'] - 1)


def yes(ok):
    return 'yes' if ok else '**no**'


def sampling_table(results):
    goal = results['settings']['temperature_goal_percent']
    rows = []
    for c in results['cases']:
        for key, label in INTEGRATORS:
            r = c['runs'].get(key)
            if r is None:
                rows.append([c['label'], label] + ['not measured'] * 7)
                continue
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
                f"({dev:+.2f}%, {'met' if abs(dev) <= goal else '**not met**'})",
                f"{r['msd_A2']['half']:.3g} / {r['msd_A2']['end']:.3g}",
                f"{r['forward_seconds']:.0f}"])
    return markdown_table(
        ['case', 'integrator', 'samples (steps)', '⟨V⟩ (Å³)',
         'g of V in steps (block length / g)',
         'κ_T (1/GPa) ± jackknife (± from g of (V − ⟨V⟩)², that g)',
         f'⟨T⟩ (K) (off target, within {goal:g}%)',
         'MSD at half / end (Å²)', 'forward wall time (s)'], rows)


def difference_table(results):
    rows = []
    for c in results['cases']:
        d = c.get('difference')
        if d is None:
            rows.append([c['label']] + ['not measured'] * 3)
            continue

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
    if not rows:
        return 'No round trip: ReversibleIsotropicNPT was not measured.'
    return markdown_table(
        ['case', 'steps each way', 'atoms and cell moved',
         'compared with np.array_equal', 'equal at the end',
         'buffer bits at the turn / after', 'wall time out / back (s)'],
        rows)


def missing(results):
    lines = [f"- {c['label']}: {c['reversible_missing']}."
             for c in results['cases'] if 'reversible_missing' in c]
    return ('\n'.join(['ReversibleIsotropicNPT was not measured:'] + lines)
            + '\n\n' if lines else '')


def warnings_seen(results):
    lines = [f"- {c['label']}, {label}: {w}"
             for c in results['cases'] for key, label in INTEGRATORS
             for w in c['runs'].get(key, {}).get('warnings', [])]
    return ('Warnings raised during the runs:\n\n' + '\n'.join(lines)
            if lines else 'No warnings were raised during the runs.')


def markdown(results):
    st = results['settings']
    load = results['load_average']
    ar = st['argon']
    return f"""\
{missing(results)}Both integrators run from the same atoms (momenta drawn at the target
temperature, seed {st['seed']}) with the same calculator, temperature,
pressure and time step, tdamp = {st['tdamp_steps']} dt and pdamp =
{st['pdamp_steps']} dt: {st['lengths_total']:,} steps each, the first
{st['lengths_equilibration']:,} equilibration, every later step a sample of
the volume V and the kinetic temperature. Copper is periodic fcc; argon is
Lennard-Jones (σ = {ar['sigma_A']} Å, ε = {ar['epsilon_eV']} eV, cut off at
{ar['cutoff_A']:.2f} Å), started on fcc sites at ρσ³ =
{ar['start_reduced_density']} and melted in the equilibration: 100 K and 50
bar are kT/ε = 0.84 and Pσ³/ε = 0.12, between the triple and critical
temperatures and above the vapour pressure, and the mean squared
displacement (MSD, from the start of the sampling) keeps growing, as in a
liquid, where copper's stays put.

Means ± standard errors come from {st['blocks']} block averages; the
isothermal compressibility κ_T = var(V) / (kT ⟨V⟩) gets its error by the
jackknife over the same blocks. g is an integrated autocorrelation time
(summed up to the first lag m ≥ {st['window_c']:g} g(m)); blocks longer
than g make the block errors trustworthy. V itself oscillates with the
piston and decorrelates fast, but var(V) is the mean of (V − ⟨V⟩)², which
follows the piston's energy and decorrelates slowly: κ_T's second error is
√(g var((V − ⟨V⟩)²) / n) / ⟨(V − ⟨V⟩)²⟩ relative, with g that of
(V − ⟨V⟩)², and the comparison below takes the larger of the two. The load average was
{load['start'][0]:.2f} at the start and {load['end'][0]:.2f} at the end
(1-minute values): the machine is shared, wall times are noisy.

{sampling_table(results)}

⟨T⟩ is ASE's `get_temperature()`, the kinetic energy over 3N degrees of
freedom, read after each step. The two thermostats make it read differently
at the same target. ReversibleIsotropicNPT's Langevin step keeps the net
momentum at zero (its noise sums to zero exactly; the start has none), so
only 3N − 3 degrees of freedom are at T and the reading is T (1 − 1/N),
−0.39% at 256 atoms; and its step is BAOAB-like (kick, drift, friction,
drift, kick), whose momenta at the end of a step are short of the
Maxwell-Boltzmann ones by a factor 1 − h²ω²/4 for a harmonic mode of
frequency ω, while the positions are not biased (the thermostat section
above estimates −0.8% for copper at 5 fs). ASE's Nosé-Hoover chain
drives the reading itself to T: with the net momentum zero (it scales every
momentum by one factor, so it stays zero) its 3N − 3 internal degrees of
freedom are at T N / (N − 1).

ReversibleIsotropicNPT minus ASE, with the combined error
√(σ_a² + σ_b²) and the difference in units of it:

{difference_table(results)}

Copper at 5 fs and at 2.5 fs tells the time-step error from a difference
of ensembles: a difference that shrinks with h² to within the errors is the
integrators' (ASE's chain thermostat holds the kinetic energy at the end of
a velocity Verlet step at T, which for a harmonic mode leaves the positions
hotter by a factor 1 / (1 − h²ω²/4); BAOAB's positions carry no such
factor), one that stays is not.

ReversibleIsotropicNPT's sampling run, reversed and run back as many steps
(no observer), against its state right after the constructor:

{round_trip_table(results)}

{warnings_seen(results)}
"""
