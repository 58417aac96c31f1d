"""ReversibleLangevin against ASE's Langevin, ReversibleBussi against ASE's
Bussi: sampling, exact reversal, information buffer, cost per step.

Measured by benchmarks/thermostat.py, whose docstring gives the method.
Besides its section of docs/benchmarks.md this module writes the Bussi
numbers of docs/thermostats.md (``DOC_BLOCKS``).
"""

from __future__ import annotations

import math

import numpy as np

from . import markdown_table, pyplot

TITLE = 'Thermostat: ReversibleLangevin against ASE Langevin'
PLOT = 'thermostat_kinetic_energy.png'

THERMOSTATS = (('reversible_langevin', 'ReversibleLangevin'),
               ('ase_langevin', 'ASE Langevin'))
BUSSI_PLOT = 'thermostat_bussi_kinetic_energy.png'
BUSSI_THERMOSTATS = (('reversible_bussi', 'ReversibleBussi'),
                     ('ase_bussi', 'ASE Bussi'))
BUSSI_SPEED_COLUMNS = (('reversible_bussi', 'ReversibleBussi'),
                       ('ase_bussi', 'ASE Bussi'),
                       ('reversible_langevin', 'ReversibleLangevin'),
                       ('velocity_verlet', 'ASE VelocityVerlet'))
SPEED_COLUMNS = (('reversible_langevin', 'ReversibleLangevin'),
                 ('ase_langevin', 'ASE Langevin'),
                 ('velocity_verlet', 'ASE VelocityVerlet'),
                 ('reversible_verlet', 'ReversibleVerlet'))
#: KS p-values below this are called a rejection.
KS_LEVEL = 0.01


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
    plt = pyplot()
    fig, axes = plt.subplots(1, len(systems), figsize=(5 * len(systems), 3.8))
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
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# -- helpers -----------------------------------------------------------------

def verdict(ok):
    return 'met' if ok else '**not met**'


def yes(ok):
    return 'yes' if ok else '**no**'


def deviation_percent(s, key):
    t = s['sampling'][key]['temperature_K']
    return 100 * (t['mean'] / s['temperature_K'] - 1)


def deviation_in_errors(s, key):
    t = s['sampling'][key]['temperature_K']
    return (t['mean'] - s['temperature_K']) / t['standard_error']


def temperature_ok(s, key, goal):
    return abs(deviation_percent(s, key)) <= goal


def bits_ratio(s, checkpoint):
    return (checkpoint['bits_per_step_per_coordinate']
            / s['buffer']['minimum_bits_per_step_per_coordinate'])


def exact(rt):
    return (rt['positions_equal'] and rt['momenta_equal']
            and rt['state_equal'] and rt['buffer_empty'])


def size(n_bytes):
    for unit, scale in (('GB', 1e9), ('MB', 1e6), ('kB', 1e3)):
        if n_bytes >= scale:
            return f'{n_bytes / scale:.3g} {unit}'
    return f'{n_bytes:.0f} B'


def us(seconds):
    return f'{seconds * 1e6:.0f}'


# -- sections ----------------------------------------------------------------

def sampling_table(results, goal, thermostats=THERMOSTATS):
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
                verdict(temperature_ok(s, key, goal)),
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
         'T_kin / T - 1', f'within {goal:g}%', 'g of K (steps)',
         'KS stride / samples / lag-1 corr.', 'KS D', 'KS p',
         'KS p, scale from ⟨K⟩',
         'E_pot (eV)', 'g of E_pot (steps)', 'max K_cm / kT'], rows)


def potential_lines(results):
    out = []
    for s in results['systems']:
        d = s['potential_difference_eV']
        se = s['potential_difference_standard_error_eV']
        out.append(f"- {s['system']} {s['n_atoms']}: ReversibleLangevin − "
                   f'ASE Langevin = {d:+.4f} ± {se:.4f} eV '
                   f'({d / se:+.1f} standard errors; '
                   f"{1e3 * d / s['n_atoms']:+.3f} meV per atom).")
    return '\n'.join(out)


def ks_lines(results, thermostats=THERMOSTATS):
    def judged(p):
        return (f'p = {p:.3g}, '
                + ('rejected' if p < KS_LEVEL else 'not rejected'))

    out = []
    for s in results['systems']:
        for key, label in thermostats:
            ks = s['sampling'][key]['ks']
            out.append(f"- {label}, {s['system']}: against Gamma at the "
                       f"target T {judged(ks['p_value'])}; with the scale "
                       f"from the measured ⟨K⟩ {judged(ks['shape_p_value'])}"
                       f' (level {KS_LEVEL:g}).')
    return '\n'.join(out)


def baoab_lines(results):
    out = []
    for s in results['systems']:
        r = s['sampling']['reversible_langevin']
        t = r['temperature_K']
        measured = 100 * (t['mean'] / s['temperature_K'] - 1)
        error = 100 * t['standard_error'] / s['temperature_K']
        out.append(f"- {s['system']} ({s['timestep_fs']:g} fs): ⟨ω²⟩ = "
                   f"{r['mean_omega_squared_per_fs2']:.3g} / fs², predicted "
                   f"{r['baoab_harmonic_kinetic_bias_percent']:+.2f}%, "
                   f'measured {measured:+.2f} ± {error:.2f}%.')
    return '\n'.join(out)


def round_trip_table(results):
    rows = []
    for s in results['systems']:
        rt = s['round_trip']
        rows.append([
            f"{s['system']} {s['n_atoms']}", f"{rt['steps_each_way']:,}",
            yes(rt['positions_equal']), yes(rt['momenta_equal']),
            yes(rt['state_equal']), yes(rt['buffer_empty']),
            f"{rt['forward_seconds']:.0f}", f"{rt['back_seconds']:.0f}",
            f"{rt['forward_seconds'] + rt['back_seconds']:.0f}"])
    return markdown_table(
        ['system', 'steps each way', 'positions equal', 'momenta equal',
         'integer state equal', 'buffer empty', 'forward (s)', 'back (s)',
         'total (s)'], rows)


def warning_lines(results, name='ReversibleLangevin'):
    out = []
    for s in results['systems']:
        for w in s['round_trip']['warnings']:
            out.append(f"- {s['system']}: `{w}`")
    return (f'Warnings {name} gave during the round trips:\n\n'
            + '\n'.join(out)) if out else \
        f'{name} gave no warning during the round trips.'


def buffer_table(results, goal):
    rows = []
    for s in results['systems']:
        b = s['buffer']
        for c in b['checkpoints']:
            rows.append([
                f"{s['system']} {s['n_atoms']}", f"{c['steps']:,}",
                f"{c['bits_per_step_per_coordinate']:.6f}",
                f"{b['minimum_bits_per_step_per_coordinate']:.6f}",
                f'{bits_ratio(s, c):.4f}',
                f"{8 * c['nbytes'] / (c['steps'] * 3 * s['n_atoms']):.4f}"])
    return markdown_table(
        ['system', 'steps', 'bits held / step / coordinate',
         'minimum −log2(c)', 'ratio', 'memory (nbytes) in bits / step / '
         'coordinate'], rows)


def memory_table(results):
    rows = []
    for s in results['systems']:
        b = s['buffer']
        for c in b['checkpoints'] + [b['extrapolated']]:
            mark = ' (extrapolated)' if c.get('extrapolated') else ''
            rows.append([
                f"{s['system']} {s['n_atoms']}", f"{c['steps']:,}{mark}",
                size(c['bits'] / 8), size(c['nbytes']),
                size(c['allocated_bytes']) if 'allocated_bytes' in c
                else '–', size(c['trajectory_bytes']),
                f"{c['trajectory_bytes'] / c['nbytes']:.0f}"])
    return markdown_table(
        ['system', 'steps', 'information held', 'buffer memory (nbytes)',
         'allocated', 'trajectory (x and p, float64)',
         'trajectory / buffer'], rows)


def forces_again_lines(results):
    out = []
    for r in results['speed']:
        again = r['get_forces_again_seconds']
        out.append(f"{r['calculator']} {r['n_atoms']}: {us(again)} µs "
                   f"({again / r['median_seconds']['velocity_verlet']:.2f} "
                   'of a VelocityVerlet step)')
    return '; '.join(out) + '.'


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


def goal_lines(results):
    st = results['settings']
    t_goal, b_goal = st['temperature_goal_percent'], st['bits_goal_ratio']
    out = []
    for s in results['systems']:
        for key, label in THERMOSTATS:
            out.append(f"- Mean kinetic temperature within {t_goal:g}% of "
                       f"the target, {label}, {s['system']}: "
                       f'{deviation_percent(s, key):+.2f}% '
                       f'({deviation_in_errors(s, key):+.1f} standard '
                       'errors), '
                       f'{verdict(temperature_ok(s, key, t_goal))}.')
    for s in results['systems']:
        rt = s['round_trip']
        out.append(f"- Exact round trip of {rt['steps_each_way']:,} steps "
                   f"each way, {s['system']}: "
                   f"{verdict(exact(rt))}.")
    for s in results['systems']:
        worst = max(bits_ratio(s, c) for c in s['buffer']['checkpoints'])
        out.append(f"- Buffer bits per step and coordinate within "
                   f"{b_goal:g}× of −log2(c), {s['system']}: at most "
                   f'×{worst:.4f}, {verdict(worst <= b_goal)}.')
    return '\n'.join(out)


def markdown(results):
    st = results['settings']
    load = results['load_average']
    systems = results['systems']
    described = '; '.join(
        f"{s['system']} {s['n_atoms']} atoms with {s['calculator']}, "
        f"{s['temperature_K']:g} K, {s['timestep_fs']:g} fs" for s in systems)
    ratio = '; '.join(
        f"{s['system']}: c = {s['buffer']['ratio_numerator']} / 65536 = "
        f"{s['buffer']['ratio']:.6f}, effective friction "
        f"{s['buffer']['effective_friction_per_fs']:.7f} / fs"
        for s in systems)
    first = systems[0]
    return f"""\
`ReversibleLangevin` (BAOAB in fixed point, friction through an
information buffer) against ASE's `Langevin`, with the same calculator,
time step, temperature and friction ({st['friction_per_fs']:g} / fs):
{described}. Momenta start from Maxwell-Boltzmann at the target with the
centre-of-mass momentum removed; both thermostats keep the centre of mass at
rest (ReversibleLangevin `fixcm=True`, whose noise has zero net momentum;
ASE `fixcm=False` with the `FixCom` constraint, because ASE 3.29 deprecates
its `fixcm=True`, which scales the noise by sqrt(N/(N−1)) so that
`get_temperature()` over 3N degrees of freedom averages T, i.e. it heats
the 3N − 3 internal ones by N/(N−1)). Seed {st['seed']} for both.

The machine is shared with other work: the load average was
{load['start'][0]:.2f} at the start, {load['before_cost'][0]:.2f} before
the cost measurement and {load['end'][0]:.2f} at the end (1-minute
values), so wall times are noisy; the wall / CPU column shows how much.

![Histogram of the internal kinetic energy against the analytic Gamma \
density, both thermostats, one panel per system](benchmarks/{PLOT})

### Sampling

Each thermostat runs {st['lengths_round_trip']:,} steps; the first
{st['lengths_equilibration']:,} are equilibration, every later step is a
sample. The kinetic energy is the internal one, K − P²/2M, so its
distribution is Gamma with shape (3N − 3)/2 (3N − 3 = {first['dof']} here)
and scale kT, and T_kin = 2⟨K⟩ / ((3N − 3) k_B). Means ± standard errors
come from {st['blocks']} block averages. g is the integrated
autocorrelation time 1 + 2 Σ ρ(t), summed up to the first lag m ≥
{st['window_c']:g} g(m). The Kolmogorov-Smirnov test (`scipy.stats.kstest`
against that Gamma distribution) takes every ceil(2 g)-th sample of K; the
lag-1 correlation of those thinned samples is given as a check that they
are decorrelated. max K_cm / kT is the largest kinetic energy of the
centre of mass seen, in kT.

{sampling_table(results, st['temperature_goal_percent'])}

Kolmogorov-Smirnov (a test with the scale estimated from the same data
is conservative; it tests the shape alone):

{ks_lines(results)}

BAOAB's momenta at the end of a full step, where both ReversibleLangevin
and an ASE observer read them, are not exactly Maxwell-Boltzmann: for a
harmonic mode of frequency ω, ⟨p²⟩ = m kT (1 − h²ω²/4) (the positions are
exact). With ⟨ω²⟩ over the internal modes estimated from the sampled
configurations of ReversibleLangevin as ⟨Σ F²/m⟩ / ((3N − 3) kT) (read
every {st['force_every']} steps), that predicts the kinetic temperature's
offset:

{baoab_lines(results)}

Mean potential energy, difference with its standard error (the two
errors added in quadrature):

{potential_lines(results)}

### Exact reversal, long

ReversibleLangevin's sampling run above is the first half of a round trip:
then `reverse()` and as many steps back, with no observer. Positions,
momenta (`np.array_equal` on `atoms`) and the integer state (`dyn.state`)
are compared with those right after the constructor; "buffer empty": every
information buffer is back at its empty state. The forward time includes
the sampling observer, which reads the energies every step.

{round_trip_table(results)}

{warning_lines(results)}

### Information buffer

Friction multiplies the momentum counts by c = n / 65536 ({ratio}). Any
exact scheme must keep at least −log2(c) bits per coordinate and step.
"Bits held" is `dyn.buffer_bits` (information in the buffers) at the
checkpoint, per step and coordinate; "memory" is the buffers' `nbytes`
(range-coder states, stack pointers and the words in use) in the same
units, and "allocated" adds the words allocated but not yet used (the
stacks grow by doubling). The trajectory is what storing positions and
momenta as float64 at every step would take. The last row of each system
is extrapolated linearly from the last two measured ones (not the
allocated bytes, which grow by doubling).

{buffer_table(results, st['bits_goal_ratio'])}

{memory_table(results)}

### Cost per step

Each integrator on its own copy of the same atoms with its own calculator;
after {st['speed']['warmup_steps']} warm-up steps, blocks of the same number
of steps (about {st['speed']['block_seconds']:g} s of ASE Langevin, at
least {st['speed']['min_steps']} steps) in {st['speed']['rounds']} rounds,
the order rotating each round (the timing helpers of `step_cost.py`).
Medians over rounds of block time / steps; ratios to ASE Langevin's median.
ASE Langevin runs with `FixCom` as above; ASE VelocityVerlet and
ReversibleVerlet (`force_purity='auto'`: 'guarded' for asap3) have no
thermostat. Round spread: the largest (max − min) / median over the
contestants; wall / CPU: the largest ratio of median wall to median CPU
time (near 1: the process had the CPU).

{speed_table(results)}

ASE's integrators ask for the forces again at unchanged positions (ASE
Langevin at the start of each step and ASE's loop after it), which costs
what the calculator's cache makes of it; measured after the rounds on the
VelocityVerlet contestant, `get_forces()` repeated:
{forces_again_lines(results)} ReversibleLangevin and ReversibleVerlet keep their own copy of the forces.

### Goals

{goal_lines(results)}

{bussi_markdown(results) if 'bussi' in results else ''}
"""


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


def bussi_buffer_table(bussi):
    rows = []
    for s in bussi['systems']:
        for c in s['buffer_checkpoints']:
            rows.append([f"{s['system']} {s['n_atoms']}", f"{c['steps']:,}",
                         f"{c['ratio_bits']:,.0f}",
                         f"{c['coordinate_bits_per_coordinate']:+.2f}",
                         f"{c['lowest_stack_pointer']} / "
                         f"{c['highest_stack_pointer']}",
                         size(c['nbytes'])])
    return markdown_table(
        ['system', 'steps', 'ratio bits', 'coordinates: bits each',
         'stack pointers low / high', 'memory'], rows)


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
    return speed_table({'speed': bussi['speed']}, BUSSI_SPEED_COLUMNS,
                       'ase_bussi')


def bussi_markdown(results):
    bussi = results['bussi']
    load = results['load_average']
    return f"""\
### Bussi: ReversibleBussi against ASE Bussi

Both with taut = {bussi['taut_fs']:g} fs and the `FixCom` constraint (both
then count 3N − 3 degrees of freedom), the same seed; liquid argon (the
fcc lattice expanded by 1.10, drawn at 600 K and melted while the
thermostat cools it to 90 K) and the copper crystal above. After
{bussi['lengths']['equilibration']:,} steps of equilibration every step of
{bussi['lengths']['steps']:,} is sampled, analysed as above.

![Histogram of the internal kinetic energy against the analytic Gamma \
density, both Bussi thermostats](benchmarks/{BUSSI_PLOT})

{bussi_sampling_lines(bussi)}

Exact reversal (the sampling run, then as many steps back):

{bussi_round_trips(bussi)}

The buffer: each step stores its ratio (32 bits); the coordinates' part
(`buffer_bits` less the ratios, per coordinate) random-walks and follows
log2 of the factor the thermostat took off the momenta since the start
(negative: reserve words were taken).

{bussi_buffer_table(bussi)}

Cost per step (interleaved as above; load average
{load.get('before_bussi', load['end'])[0]:.2f} before this part):

{bussi_speed_table(bussi)}
"""


def bussi_doc_block(stored):
    """The numbers of docs/thermostats.md's ReversibleBussi section."""
    results = stored['results']
    if 'bussi' not in results:
        return 'Not measured yet: run `python benchmarks/run_all.py --only ' \
            'thermostat`.'
    bussi = results['bussi']
    return (f"*Measured {stored['date'][:10]} by `{stored['command']}`"
            + (' (quick mode)' if stored['quick'] else '') + '.*\n\n'
            + bussi_sampling_lines(bussi) + '\n\n'
            + bussi_round_trips(bussi) + '\n\n'
            + bussi_buffer_table(bussi) + '\n\n'
            + bussi_speed_table(bussi))


#: Blocks of other pages this module writes: render.py replaces what lies
#: between the block's markers.
DOC_BLOCKS = {('thermostats.md', 'bussi'): bussi_doc_block}
