"""Work against precision (benchmarks/work_precision.py)."""

from __future__ import annotations

from . import Spec, markdown_table, pyplot


def plot_name(system):
    return f"work_precision_{system['key']}.png"


def plot(results, figures):
    for system in results['systems']:
        _plot_system(system, results['target'], figures)


STYLE = {2: 'C0', 4: 'C1', 6: 'C2', 8: 'C3', 10: 'C4'}


def _style(sweep):
    if sweep['scheme'] is None:
        # On top: velocity 2 has the same errors and would hide it.
        return dict(color='black', linestyle='-', marker='o', zorder=3,
                    linewidth=1, markersize=3)
    return dict(color=STYLE[sweep['order']], zorder=2,
                linestyle='-' if sweep['scheme'] == 'velocity' else '--',
                marker='s' if sweep['scheme'] == 'velocity' else '^',
                markerfacecolor='none' if sweep['scheme'] == 'position'
                else None)


def _plot_system(result, target, figures):
    plt = pyplot()
    fig, (ax_work, ax_dt) = plt.subplots(1, 2, figsize=(12, 5))
    for s in result['sweeps']:
        pts = [p for p in s['points'] if p['max_error'] is not None]
        if not pts:
            continue
        style = _style(s)
        ax_work.plot([p['wall_s'] for p in pts], [p['max_error'] for p in pts],
                     label=s['method'], **{'markersize': 4, **style})
        ax_dt.plot([p['dt_fs'] for p in pts], [p['max_error'] for p in pts],
                   label=s['method'], **{'markersize': 4, **style})
    for ax in (ax_work, ax_dt):
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.axhline(target, color='grey', linewidth=0.8, linestyle=':')
        ax.grid(True, which='major', alpha=0.3)
    ax_work.set_xlabel('wall time of the run without sampling (s)')
    ax_dt.set_xlabel('time step (fs)')
    for ax in (ax_work, ax_dt):
        ax.set_ylabel('max relative total-energy error')
    ax_work.set_title(f"{result['label']}: {result['formula']}, "
                      f"{result['simulated_fs']:g} fs")
    ax_dt.set_title('error against time step')
    ax_dt.legend(fontsize=7, ncol=2)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.11, top=0.93,
                        wspace=0.22)
    fig.savefig(figures / plot_name(result), dpi=110)
    plt.close(fig)


# -- Markdown ----------------------------------------------------------------

def _g(x, digits=3):
    return '–' if x is None else f'{x:.{digits}g}'


def _e(x):
    return '–' if x is None else f'{x:.2e}'


def _time_cell(row, key):
    if row[key] is None:
        return 'not reached'
    prefix = '≤ ' if row['how'] == 'at most' else ''
    return f'{prefix}{row[key]:.3g} s'


def summary(r):
    """The system, and each method's time to the target."""
    e0_atom = r['initial_energy_eV'] / r['atoms']
    lines = []
    if r['pbc']:
        desc = (f"{r['formula']} ({r['atoms']} atoms), periodic fcc, "
                f"`{r['calculator']}` (Cleri–Rosato parameters), "
                f"thermalised at {r['temperature_K']:g} K from the perfect "
                f"lattice; E(0) = {e0_atom:.4g} eV/atom.")
    else:
        desc = (f"{r['formula']} icosahedron ({r['atoms']} atoms) in "
                f"vacuum, `{r['calculator']}` (behind `ResultCache`, see "
                f"below) with cutoff "
                f"{r['cutoff']:g} Å; the widest interatomic distance in "
                f"any sample was {r['widest_distance']:.1f} Å, far inside "
                f"the cutoff, so no pair crosses it.  Thermalised at "
                f"{r['temperature_K']:g} K; E(0) = {e0_atom:.4g} eV/atom.")
    lines += [desc + f"  Simulated time {r['simulated_fs']:g} fs, energy "
              f"sampled every {r['interval_fs']:g} fs.", '']

    rows = r['summary']
    table = []
    for row in rows:
        table.append([row['method'], row['stages'],
                      _time_cell(row, 'wall_s'), _g(row['wall_s_ratio']),
                      _time_cell(row, 'cpu_s'), _g(row['cpu_s_ratio']),
                      _e(row['best_error']), row['stop']])
    lines += [markdown_table(
        ['method', 'force calls / step', 'wall to target', 'wall ratio',
         'CPU to target', 'CPU ratio', 'best error', 'stop'], table)]
    return '\n'.join(lines)


def of_system(make, key):
    """A block of the system ``key`` (a line where this run has none)."""
    def markdown(stored):
        found = [r for r in stored['results']['systems'] if r['key'] == key]
        return make(found[0]) if found else '*Not measured in this run.*'
    return markdown


SPEC = Spec(
    'Work against precision',
    blocks={**{key: of_system(summary, key)
               for key in ('argon_cluster', 'copper_crystal')}},
    plots=(plot,),
    values=lambda results: {
        **{r['key']: r for r in results['systems']},
        'ladder_start': ', '.join(map(str, results['ladder'][:7]))})
