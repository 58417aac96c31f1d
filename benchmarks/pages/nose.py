"""ReversibleNose against ASE's thermostats: sampling, exact reversal,
memory against steps, cost per step.

Measured by benchmarks/nose.py, whose docstring gives the method.
"""

from __future__ import annotations

import numpy as np

from . import markdown_table, pyplot
from .thermostat import (deviation_in_errors, deviation_percent,
                         forces_again_lines, histograms, ks_lines,
                         sampling_table, size, speed_table, temperature_ok,
                         verdict, warning_lines, yes)

TITLE = "Nosé thermostat: ReversibleNose against ASE's thermostats"
PLOT = 'nose_kinetic_energy.png'
PLOT_S = 'nose_thermostat_position.png'

THERMOSTATS = (('reversible_nose', 'ReversibleNose'),
               ('ase_langevin', 'ASE Langevin'))
SPEED_COLUMNS = (('reversible_nose', 'ReversibleNose'),
                 ('ase_nose_hoover_chain', 'ASE NoseHooverChainNVT'),
                 ('ase_langevin', 'ASE Langevin'),
                 ('velocity_verlet', 'ASE VelocityVerlet'),
                 ('reversible_verlet', 'ReversibleVerlet'))
COUNTS = ('position', 'momentum', 'thermostat_position',
          'thermostat_momentum', 'time')


def plot(results, figures):
    systems = results['systems']
    histograms(systems, THERMOSTATS, figures / PLOT)

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.4))
    for s, color in zip(systems, ('C0', 'C1')):
        th = s['thermostat']
        trace = np.asarray(th['s_trace'])
        steps = np.arange(len(trace)) * th['s_trace_every']
        ax.plot(steps * s['timestep_fs'] / 1000, trace, color=color, lw=0.6,
                label=f"{s['system']} {s['n_atoms']}, tdamp "
                      f"{th['tdamp_fs']:g} fs")
    first = systems[0]
    ax.axvline(first['equilibration_steps'] * first['timestep_fs'] / 1000,
               color='k', lw=0.8, ls=':', label='end of equilibration')
    ax.set_xlabel('virtual time (ps)')
    ax.set_ylabel('s (real step = dt / s)')
    ax.set_title(f"Nosé's s over the forward run, every "
                 f"{first['thermostat']['s_trace_every']} steps", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figures / PLOT_S, dpi=110)
    plt.close(fig)


# -- judgements --------------------------------------------------------------

def ks_ok(s, level):
    return s['sampling']['reversible_nose']['ks']['p_value'] >= level


def potential_in_errors(s):
    return (s['potential_difference_eV']
            / s['potential_difference_standard_error_eV'])


def exact(rt):
    return (all(rt['counts_equal'].values()) and rt['positions_equal']
            and rt['momenta_equal'])


def last_decade(points, key):
    """Ratio of ``key`` at the last point to the one before."""
    return points[-1][key] / points[-2][key]


def cost_ratio(r):
    med = r['median_seconds']
    return med['reversible_nose'] / med['ase_nose_hoover_chain']


# -- sections ----------------------------------------------------------------

def thermostat_table(results):
    rows = []
    for s in results['systems']:
        th = s['thermostat']
        sv, rs, e = th['s'], th['real_timestep_fs'], th['extended_energy_eV']
        rt = s['round_trip']
        real_over_virtual = rt['real_time_forward_fs'] / (
            rt['steps_each_way'] * s['timestep_fs'])
        rows.append([
            f"{s['system']} {s['n_atoms']}",
            f"{sv['mean']:.4f} ± {sv['standard_error']:.4f}",
            f"{sv['std']:.4f}", f"{sv['min']:.3f} – {sv['max']:.3f}",
            f"{th['s_from_start']['min']:.3f} – "
            f"{th['s_from_start']['max']:.3f}",
            f"{sv['correlation_time_steps']:.0f}",
            f"{rs['mean']:.3f} ({rs['min']:.3f} – {rs['max']:.3f})",
            f'{real_over_virtual:.4f}',
            f"{1e3 * e['max_deviation'] / s['n_atoms']:.3f}",
            f"{1e3 * (e['last'] - e['first']) / s['n_atoms']:+.3f}"])
    return markdown_table(
        ['system', 's (mean ± SE)', 's std', 's range, sampled',
         's range, from the start', 'g of s (steps)',
         'real step dt / s (fs): mean (range)', 'real time / (steps × dt)',
         'extended energy: max |E − E₀| (meV/atom)',
         'last − first (meV/atom)'], rows)


def harmonic_lines(results):
    out = []
    for s in results['systems']:
        r = s['sampling']['reversible_nose']
        th = s['thermostat']
        t = r['temperature_K']
        measured = 100 * (t['mean'] / s['temperature_K'] - 1)
        error = 100 * t['standard_error'] / s['temperature_K']
        out.append(f"- {s['system']} ({s['timestep_fs']:g} fs, rms real step "
                   f"{th['real_timestep_fs']['rms']:.3f} fs): ⟨ω²⟩ = "
                   f"{r['mean_omega_squared_per_fs2']:.3g} / fs², estimate "
                   f"{th['harmonic_kinetic_offset_percent']:+.2f}%, measured "
                   f'{measured:+.2f} ± {error:.2f}%.')
    return '\n'.join(out)


def potential_lines(results, goal):
    out = []
    for s in results['systems']:
        d = s['potential_difference_eV']
        se = s['potential_difference_standard_error_eV']
        out.append(f"- {s['system']} {s['n_atoms']}: ReversibleNose − "
                   f'ASE Langevin = {d:+.4f} ± {se:.4f} eV '
                   f'({d / se:+.1f} standard errors; '
                   f"{1e3 * d / s['n_atoms']:+.3f} meV per atom): within "
                   f'{goal:g} standard errors '
                   f'{yes(abs(d / se) <= goal)}.')
    return '\n'.join(out)


def round_trip_table(results):
    rows = []
    for s in results['systems']:
        rt = s['round_trip']
        rows.append(
            [f"{s['system']} {s['n_atoms']}", f"{rt['steps_each_way']:,}"]
            + [yes(rt['counts_equal'][k]) if k in rt['counts_equal']
               else '–' for k in COUNTS]
            + [yes(rt['positions_equal']), yes(rt['momenta_equal']),
               f"{rt['time_after_fs']:g}",
               f"{rt['forward_seconds']:.0f}", f"{rt['back_seconds']:.0f}",
               f"{rt['forward_seconds'] + rt['back_seconds']:.0f}"])
    return markdown_table(
        ['system', 'steps each way']
        + [f'counts `{k}` equal' for k in COUNTS]
        + ['atoms: positions equal', 'atoms: momenta equal',
           'get_time() after (fs)', 'forward (s)', 'back (s)',
           'total (s)'], rows)


def memory_table(results):
    m = results['memory']
    rows = []
    for r in m['nose']:
        resident = r['resident_bytes']
        grown = (size(resident[-1] - resident[0])
                 if None not in resident else '–')
        rows.append([
            f"{r['steps']:,}", size(r['forward_traced_peak_bytes']),
            size(r['forward_traced_end_bytes']),
            size(r['backpropagate_traced_peak_bytes']),
            size(r['backpropagate_traced_end_bytes']), grown,
            yes(r['counts_equal_after_backpropagate']),
            f"{r['hessian_vector_products']:,}",
            f"{r['gradient_max_abs']:.2g}"
            + ('' if r['gradient_finite'] else ' (**not finite**)'),
            f"{r['forward_seconds']:.1f} / {r['backpropagate_seconds']:.1f}"])
    return markdown_table(
        ['steps N', 'run(N): traced peak', 'held after run',
         'backpropagate(N): traced peak', 'held after backpropagate',
         'resident size, end − start', 'counts back at the start',
         'Hessian-vector products', 'max |gradient|',
         'run / backpropagate (s, traced)'], rows)


def comparison_table(results):
    m = results['memory']
    langevin = {c['steps']: c for c in m['langevin']['checkpoints']}
    rows = []
    for r in m['nose']:
        c = langevin.get(r['steps'])
        peak = max(r['forward_traced_peak_bytes'],
                   r['backpropagate_traced_peak_bytes'])
        rows.append([
            f"{r['steps']:,}", size(peak),
            size(c['nbytes']) if c else '–',
            size(c['allocated_bytes']) if c else '–',
            size(c['traced_bytes']) if c else '–',
            size(r['trajectory_bytes'])])
    return markdown_table(
        ['steps', 'ReversibleNose: largest traced peak',
         'ReversibleLangevin: buffer (nbytes)', 'buffer allocated',
         'ReversibleLangevin: traced memory held',
         'trajectory (x and p, float64)'], rows)


def memory_lines(results):
    m = results['memory']
    nose = m['nose']
    lo, hi = nose[0], nose[-1]
    out = []
    for key, label in (('forward_traced_peak_bytes', 'run'),
                       ('backpropagate_traced_peak_bytes', 'backpropagate')):
        out.append(f"- {label}: traced peak ×{last_decade(nose, key):.3f} "
                   f"from {nose[-2]['steps']:,} to {hi['steps']:,} steps, "
                   f"×{hi[key] / lo[key]:.3f} from {lo['steps']:,}.")
    for key, label in (('forward_traced_end_bytes', 'run'),
                       ('backpropagate_traced_end_bytes', 'backpropagate')):
        grown = hi[key] - nose[-2][key]
        out.append(f'- held after {label}: {size(abs(grown))} '
                   f"{'more' if grown >= 0 else 'less'} at "
                   f"{hi['steps']:,} steps than at {nose[-2]['steps']:,} "
                   f"({grown / (hi['steps'] - nose[-2]['steps']):+.3f} bytes "
                   'per step).')
    points = m['langevin']['checkpoints']
    grown = points[-1]['nbytes'] - points[-2]['nbytes']
    out.append(f"- ReversibleLangevin's buffer grows by "
               f"{grown / (points[-1]['steps'] - points[-2]['steps']):.2f} "
               'bytes per step.')
    out.append(f"- ReversibleLangevin's buffer: "
               f"×{last_decade(points, 'nbytes'):.2f} from "
               f"{points[-2]['steps']:,} to {points[-1]['steps']:,} steps.")
    return '\n'.join(out)


def profile_lines(results):
    prof = results['memory'].get('profile')
    if not prof:
        return ''
    interval = prof['spot_check_interval']
    largest = ', '.join(
        f"{p['step']:,} ({size(p['peak_bytes'])}; mod {interval}: "
        f"{p['step'] % interval})" for p in prof['largest'])
    return (f"Which steps allocate most: a run of {prof['steps']:,} steps "
            'with an observer that reads the traced peak after every step '
            'and resets it. Median peak of a step '
            f"{size(prof['median_step_peak_bytes'])}; the "
            f"{len(prof['largest'])} largest, by step: {largest}. The "
            'extended energy is checked every '
            f"{prof['energy_check_interval']} steps and the force provider "
            f'spot-checks purity every {interval} force calls '
            '(`ase_reversible.purity.SpotCheck`); a peak such a step makes '
            'is in the peak of a run only once the run is long enough to '
            'contain it.')


def memory_warning_lines(results):
    m = results['memory']
    seen = sorted({w for r in m['nose'] + [m['langevin']]
                   for w in r.get('warnings', ())})
    return ('Warnings in the memory workers, each with how often it came in '
            'its worker:\n\n'
            + '\n'.join(f'- `{w}`' for w in seen)) if seen else \
        'The memory workers gave no warning.'


def goal_lines(results):
    st = results['settings']
    t_goal, level = st['temperature_goal_percent'], st['ks_level']
    e_goal = st['potential_goal_standard_errors']
    out = []
    for s in results['systems']:
        out.append(f"- Mean kinetic temperature of ReversibleNose within "
                   f"{t_goal:g}% of the target, {s['system']}: "
                   f"{deviation_percent(s, 'reversible_nose'):+.2f}% "
                   f"({deviation_in_errors(s, 'reversible_nose'):+.1f} "
                   'standard errors), '
                   f"{verdict(temperature_ok(s, 'reversible_nose', t_goal))}.")
    for s in results['systems']:
        p = s['sampling']['reversible_nose']['ks']['p_value']
        out.append(f"- Internal kinetic energy of ReversibleNose not rejected "
                   f"as Gamma at the target T (KS p ≥ {level:g}), "
                   f"{s['system']}: p = {p:.3g}, "
                   f'{verdict(ks_ok(s, level))}.')
    for s in results['systems']:
        z = potential_in_errors(s)
        out.append(f"- Mean potential energy equal to ASE Langevin's within "
                   f"{e_goal:g} standard errors, {s['system']}: "
                   f"{s['potential_difference_eV']:+.4f} eV ({z:+.1f} "
                   f'standard errors), {verdict(abs(z) <= e_goal)}.')
    for s in results['systems']:
        rt = s['round_trip']
        out.append(f"- Exact round trip of {rt['steps_each_way']:,} steps "
                   f"each way (every entry of `dyn.counts`), {s['system']}: "
                   f'{verdict(exact(rt))}.')
    nose = results['memory']['nose']
    goal = st['memory_goal_ratio']
    for key, label in (('forward_traced_peak_bytes', 'run(N)'),
                       ('backpropagate_traced_peak_bytes',
                        'backpropagate(N)')):
        ratio = last_decade(nose, key)
        out.append(f"- Memory of {label} flat: traced peak at "
                   f"{nose[-1]['steps']:,} steps within ×{goal:g} of that at "
                   f"{nose[-2]['steps']:,}: ×{ratio:.3f}, "
                   f'{verdict(ratio <= goal)}.')
    back = all(r['counts_equal_after_backpropagate'] for r in nose)
    steps = ', '.join(f"{r['steps']:,}" for r in nose)
    out.append(f'- backpropagate(N) ends on the counts of the start, N = '
               f'{steps}: {verdict(back)}.')
    c_goal = st['cost_goal_ratio']
    for r in results['speed']:
        ratio = cost_ratio(r)
        out.append(f"- Cost per step at most {c_goal:g}× ASE "
                   f"NoseHooverChainNVT's, {r['calculator']} {r['n_atoms']}: "
                   f'×{ratio:.2f}, {verdict(ratio <= c_goal)}.')
    return '\n'.join(out)


def markdown(results):
    st = results['settings']
    load = results['load_average']
    systems = results['systems']
    m = results['memory']
    described = '; '.join(
        f"{s['system']} {s['n_atoms']} atoms with {s['calculator']}, "
        f"{s['temperature_K']:g} K, {s['timestep_fs']:g} fs, tdamp "
        f"{s['thermostat']['tdamp_fs']:g} fs" for s in systems)
    first = systems[0]
    return f"""\
`ReversibleNose` (Nosé's extended system in virtual time, every update an
exact shear, no buffer) against ASE's `Langevin` for sampling and against
ASE's `NoseHooverChainNVT`, `Langevin` and `VelocityVerlet` for cost:
{described} (tdamp = {st['tdamp_steps']} time steps; the thermostat's mass
is Q = g kT tdamp² with g = N_f + 1, N_f =
{first['thermostat']['degrees_of_freedom']} free momentum coordinates for
{first['n_atoms']} atoms). ASE Langevin runs as in the
section above: friction {st['langevin_friction_per_fs']:g} / fs, `FixCom`,
seed {st['langevin_seed']}.

Where a Nosé run starts matters: `s` is not pulled back to 1 but settles
wherever the extended energy puts it, and the real time step is dt / s.
From a perfect lattice with momenta drawn at T, equipartition leaves the
atoms near T / 2 and the thermostat has to pour in about 1.5 N kT, which
g kT ln s pays for: ln s ≈ −1.5 N kT / (3N kT), s ≈ 0.6, a real step 1.6
times dt. So the momenta are drawn at {st['start_factor']:g} T on
the bare lattice (copper not rattled) and the centre-of-mass momentum
removed; equipartition turns that into about T. Both thermostats start
from these atoms.

The machine is shared with other work: the load average was
{load['start'][0]:.2f} at the start, {load['before_memory'][0]:.2f} before
the memory measurement, {load['before_cost'][0]:.2f} before the cost
measurement and {load['end'][0]:.2f} at the end (1-minute values), so wall
times are noisy; the wall / CPU column shows how much.

![Histogram of the internal kinetic energy against the analytic Gamma \
density, ReversibleNose and ASE Langevin, one panel per system](benchmarks/{PLOT})

![Nosé's s against virtual time over the forward run, both \
systems](benchmarks/{PLOT_S})

### Sampling

Each thermostat runs {st['lengths_round_trip']:,} steps; the first
{st['lengths_equilibration']:,} are equilibration, every later step is a
sample (for ReversibleNose a frame in virtual time, which is what Nosé's g
= N_f + 1 makes canonical). The kinetic energy is the internal one, K −
P²/2M, with distribution Gamma with shape (3N − 3)/2 (3N − 3 =
{first['dof']} here, ReversibleNose's N_f) and scale kT, and T_kin =
2⟨K⟩ / ((3N − 3) k_B). Means ± standard errors come from {st['blocks']}
block averages; g is the integrated autocorrelation time summed up to the
first lag m ≥ {st['window_c']:g} g(m); the Kolmogorov-Smirnov test takes
every ceil(2 g)-th sample of K (as in the section above).

{sampling_table(results, st['temperature_goal_percent'], THERMOSTATS)}

Kolmogorov-Smirnov:

{ks_lines(results, THERMOSTATS)}

The thermostat, over the sampled steps unless said otherwise ("from the
start" includes the equilibration); the extended energy is read every
{st['force_every']} steps:

{thermostat_table(results)}

The π kicks read the momenta between the step's two half kicks, so those
are what the thermostat steers to T. If they are at T, then for a harmonic
mode of frequency ω the momenta at the step's end, where they are read
here, are cooler by a factor 1 − h²ω²/4, h the real step dt / s (as for
BAOAB in the section above). A harmonic estimate, with ⟨ω²⟩ over the
internal modes from ⟨Σ F²/m⟩ / ((3N − 3) kT) (read every
{st['force_every']} steps) and h² from ⟨(dt / s)²⟩:

{harmonic_lines(results)}

Mean potential energy, difference with its standard error (the two errors
added in quadrature):

{potential_lines(results, st['potential_goal_standard_errors'])}

### Exact reversal, long

ReversibleNose's sampling run is the first half of a round trip: then
`reverse()` and as many steps back with no observer. Every entry of
`dyn.counts` is compared with the counts right after the constructor
(`np.array_equal`), and so are the positions and momenta the atoms show.
The forward time includes the sampling observer.

{round_trip_table(results)}

{warning_lines(results, 'ReversibleNose')}

### Memory against steps

{m['system']} {m['n_atoms']} atoms, {m['calculator']},
{m['temperature_K']:g} K, {m['timestep_fs']:g} fs, started as above. Each
ReversibleNose point is a fresh process that builds the system and the
integrator and only then starts `tracemalloc`: the traced peak of
`run(N)`, then (peak reset) of `backpropagate(N, ...)` for a fixed random
loss gradient with finite-difference Hessian-vector products (asap3 has no
analytic Hessian), and the memory still held after each. ReversibleLangevin
(friction {m['friction_per_fs']:g} / fs) runs in one more process to the
same step counts: its information buffers (`nbytes`, and the words
allocated) and the traced memory it holds. {m['parallel_workers']} workers
run at a time; their times are with `tracemalloc` on. The gradient of a
chaotic system grows exponentially with N; "max |gradient|" shows it stayed
finite. A traced peak is the largest transient a run met, not memory that
accumulates, so flatness is judged from the last two points (see the
profile below); a ratio near the goal's ×{st['memory_goal_ratio']:g} can
fall either side of it from one run to the next.

{memory_table(results)}

{comparison_table(results)}

{memory_lines(results)}

{profile_lines(results)}

{memory_warning_lines(results)}

### Cost per step

Copper with asap3 EMT; each integrator on its own copy of the same atoms
with its own calculator, after {st['speed']['warmup_steps']} warm-up steps,
blocks of the same number of steps (about {st['speed']['block_seconds']:g} s
of ASE NoseHooverChainNVT, at least {st['speed']['min_steps']} steps) in
{st['speed']['rounds']} rounds, the order rotating each round
(`thermostat.speed_case`). Medians over rounds; ratios to ASE
NoseHooverChainNVT's median. NoseHooverChainNVT has ASE's defaults (a
chain of 3) and the same tdamp; ASE Langevin runs with `FixCom` as above;
ASE VelocityVerlet and ReversibleVerlet have no thermostat.

{speed_table(results, SPEED_COLUMNS, 'ase_nose_hoover_chain')}

ASE's integrators ask for the forces again at unchanged positions; measured
on the VelocityVerlet contestant, `get_forces()` repeated:
{forces_again_lines(results)}

### Goals

{goal_lines(results)}
"""


# -- the studies (benchmarks/nose.py --study timestep|chain) ----------------

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
        return ('Not measured yet: `python benchmarks/nose.py --study '
                'timestep`.')
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
    lengths = study['lengths']
    return f"""\
{study['system']}, thermostats at {study['temperature_K']:g} K with tdamp =
{study['tdamp_steps']} steps; {lengths['equilibration']:,} steps of
equilibration, then {lengths['sampled']:,} steps sampled every
{study['sample_every']} (means ± standard errors of {study['blocks']}
blocks). "Half kicked" is the temperature of `(p' + dt F / 2) / s`, the
momenta the velocity scheme's thermostat kick reads; ⟨U⟩ − ⟨U⟩(2 fs) is
taken against the same integrator's 2 fs run.

{markdown_table(['dt (fs)', 'integrator', 'T on-step (K)',
                 'T half kicked (K)', '⟨U⟩ (eV)', '⟨U⟩ − ⟨U⟩(2 fs) (eV)',
                 'std U (eV)'], rows)}

{_study_line(study)}
"""


def chain_block(stored):
    """docs/thermostats.md, "A chain of thermostats": the measured table."""
    study = stored['results'].get('chain')
    if study is None:
        return 'Not measured yet: `python benchmarks/nose.py --study chain`.'
    rows = []
    for c in study['cases']:
        if c.get('failure'):
            rows.append([f"{c['system']} {c['n_atoms']}, "
                         f"{c['temperature_K']:g} K, {c['timestep_fs']:g} fs",
                         c['tchain'], c['failure'], '', '', '', '',
                         ', '.join(f'{a:.2f}–{b:.2f}'
                                   for a, b in c['s_range']), '', ''])
            continue
        ks = c['sampling']['ks']
        e = c['thermostat']['extended_energy_eV']
        s_ranges = ', '.join(f'{a:.2f}–{b:.2f}' for a, b in c['s_range'])
        exact = c.get('round_trip_equal')
        rows.append([
            f"{c['system']} {c['n_atoms']}, {c['temperature_K']:g} K, "
            f"{c['timestep_fs']:g} fs", c['tchain'],
            _mean_se(c['sampling']['temperature_K']),
            f"{ks['p_value']:.2g}", f"{ks['shape_p_value']:.2g}",
            f"{c['half_kicked']['ks']['p_value']:.2g}",
            f"{e['std']:.2g} / {e['max_deviation']:.2g}", s_ranges,
            f"{c['mean_square_displacement_A2']:.2g}",
            '' if exact is None else yes(all(exact.values()))])
    speed = study['speed']
    median = speed['median_seconds']
    lengths = study['lengths']
    chain = median['reversible_nose_tchain3'] / median['reversible_nose']
    ase = median['reversible_nose_tchain3'] / median['ase_nose_hoover_chain']
    scheme = study['cases'][0]['scheme']
    return f"""\
Momenta drawn at twice the target on the lattice (copper; argon melted
first by ASE's `Langevin` at the target), `scheme='{scheme}'`,
tdamp = {study['tdamp_steps']} steps, {lengths['equilibration']:,} steps
of equilibration and {lengths['sampled']:,} sampled, every step. KS: the
Kolmogorov-Smirnov p-value of the internal kinetic energy against the
canonical Gamma distribution on samples thinned to twice its correlation
time; "shape" takes the scale from the measured mean (so it tests the
distribution's shape, not the time-step offset of the mean); "half
kicked" tests, with the scale kT, the kinetic energy of `(p' + dt F / 2) /
s_1`, which the thermostat reads (section above). H: the
extended energy's standard deviation / largest change from the start
(eV). MSD: mean square displacement over the run (Å²), which tells the
liquid from the crystal.

{markdown_table(['system', 'tchain', 'T (K)', 'KS p', 'KS p (shape)',
                 'KS p (half kicked)', 'H std / max change (eV)',
                 's_1 … s_M range', 'MSD (Å²)', 'back bit for bit'], rows)}

Cost per step, {speed['n_atoms']} copper atoms with asap3 EMT, interleaved
rounds (medians): tchain=3 {median['reversible_nose_tchain3'] * 1e3:.2f}
ms, tchain=1 {median['reversible_nose'] * 1e3:.2f} ms (ratio {chain:.3f}),
ASE NoseHooverChainNVT {median['ase_nose_hoover_chain'] * 1e3:.2f} ms
(tchain=3 over ASE: {ase:.3f}).

{_study_line(study)}
"""


def chain_stability_block(stored):
    """docs/thermostats.md, "A chain of thermostats": which runs lasted."""
    study = stored['results'].get('chain')
    if study is None or 'stability' not in study:
        return 'Not measured yet: `python benchmarks/nose.py --study chain`.'
    rows = []
    for c in study['stability']:
        rows.append([f"{c['system']} {c['n_atoms']}, {c['timestep_fs']:g} fs",
                     c['tdamp_steps'], c['tchain'],
                     c['failure'] or f"ran {c['steps']:,} steps",
                     f"{c['largest_change_kT']:.3g}"])
    return markdown_table(['system', 'tdamp (steps)', 'tchain', 'outcome',
                           'largest change of H (kT)'], rows)


#: docs pages this section writes numbers into (render.py replaces what
#: lies between each block's markers).
DOC_BLOCKS = {('thermostats.md', 'timestep'): timestep_block,
              ('thermostats.md', 'chain-stability'): chain_stability_block,
              ('thermostats.md', 'chain'): chain_block}
