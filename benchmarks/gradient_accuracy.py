"""Accuracy of the reversible adjoint's gradients.

Two sources of error are measured separately:

1. **Finite-difference Hessian-vector products** (for calculators without
   exact ones): ``FiniteDifferenceHVP(step)`` against a reference, over a
   sweep of steps.  The reference is exact for the package's LennardJones
   (its analytic product) and a fourth-order stencil at 1e-5 Å for EMT
   (its truncation, ~step**4, is far below the errors measured).
2. **Whole-run gradients** from ``backpropagate`` against central finite
   differences of the whole ReversibleVerlet run (fine quanta, fresh
   integrator per run) along random directions, for runs of growing length.
   The gradient's growth over the run (largest component of dL/d(x0, p0)
   over that of dL/d(x_T, p_T)) shows how chaotic the run is; the finite
   differences' own error grows with it (their truncation ~h**2 times the
   curvature of the run map), so the smallest error over three h is given.
"""

from __future__ import annotations

import common

import time

import numpy as np

TITLE = 'Gradient accuracy'

FINE = {'position_quantum': 2.0**-44, 'momentum_quantum': 2.0**-46,
        'energy_check': 0}
STEPS_FD = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6)
FD_H = (1e-5, 1e-6, 1e-7)


def _hvp_cases():
    import asap3
    from ase.build import bulk
    from ase.calculators.emt import EMT
    from ase.cluster import Icosahedron
    from ase_reversible import LennardJones

    def argon():
        atoms = Icosahedron('Ar', 4, latticeconstant=5.26)
        atoms.rattle(0.1, seed=1)
        atoms.calc = LennardJones(epsilon=0.0104, sigma=3.4)
        return atoms

    def copper(calc):
        def build():
            atoms = bulk('Cu', cubic=True) * (4, 4, 4)
            atoms.rattle(0.05, seed=1)
            atoms.calc = calc()
            return atoms
        return build

    return (('Ar147 cluster, package LennardJones', argon, 'analytic'),
            ('Cu256 crystal, asap3 EMT', copper(asap3.EMT), 'stencil'),
            ('Cu256 crystal, ASE EMT', copper(EMT), 'stencil'))


def _stencil(atoms, v_nc, step):
    """Fourth-order central difference of -F along v (max move ``step``)."""
    e = step / np.abs(v_nc).max()
    x_nc = atoms.positions.copy()
    f = {}
    for k in (-2, -1, 1, 2):
        atoms.positions = x_nc + k * e * v_nc
        f[k] = atoms.get_forces(apply_constraint=False)
    atoms.positions = x_nc
    return -(f[-2] - 8 * f[-1] + 8 * f[1] - f[2]) / (12 * e)


def measure_hvp(quick):
    from ase_reversible import FiniteDifferenceHVP
    from ase_reversible.hessian import DEFAULT_FD_STEP
    rows = []
    cases = _hvp_cases()[:2] if quick else _hvp_cases()
    for label, build, kind in cases:
        atoms = build()
        v_nc = np.random.default_rng(0).normal(size=(len(atoms), 3))
        reference_nc = (atoms.calc.hessian_vector_product(atoms, v_nc)
                        if kind == 'analytic'
                        else _stencil(atoms, v_nc, 1e-5))
        scale = np.abs(reference_nc).max()
        errors = {}
        for step in STEPS_FD:
            hv_nc = FiniteDifferenceHVP(step)(atoms, v_nc)
            errors[step] = float(np.abs(hv_nc - reference_nc).max() / scale)
        rows.append({'case': label, 'n_atoms': len(atoms), 'reference': kind,
                     'errors': {repr(k): v for k, v in errors.items()},
                     'default_step': DEFAULT_FD_STEP})
    return rows


def _run_cases(quick):
    from ase.calculators.emt import EMT
    from ase.cluster import Icosahedron
    from ase_reversible import LennardJones
    from ase_reversible.demo import thermalize

    def argon():
        atoms = Icosahedron('Ar', 3, latticeconstant=5.26)
        atoms.center(vacuum=10.0)
        thermalize(atoms, 60, 0)
        atoms.calc = LennardJones(epsilon=0.0104, sigma=3.4)
        return atoms

    def copper():
        atoms = Icosahedron('Cu', 2)
        atoms.center(vacuum=8.0)
        thermalize(atoms, 600, 0)
        atoms.calc = EMT()
        return atoms

    if quick:
        return (('Ar55 at 60 K, package LennardJones (exact products)',
                 argon, (100, 400), 1),)
    return (('Ar55 at 60 K, package LennardJones (exact products)', argon,
             (250, 500, 1000, 2000, 4000), 3),
            ('Cu13 at 600 K, ASE EMT (finite-difference products)', copper,
             (50, 100, 200, 300, 400), 3))


def _loss_run(build, steps, a_nc, b_nc, dx_nc=0.0, dp_nc=0.0):
    from ase import units
    from ase_reversible import ReversibleVerlet
    atoms = build()
    atoms.positions = atoms.positions + dx_nc
    atoms.set_momenta(atoms.get_momenta() + dp_nc)
    ReversibleVerlet(atoms, 5 * units.fs, **FINE).run(steps)
    return float(np.vdot(a_nc, atoms.positions)
                 + np.vdot(b_nc, atoms.get_momenta()))


def measure_runs(quick):
    from ase import units
    from ase_reversible import ReversibleVerlet
    results = []
    for label, build, lengths, directions in _run_cases(quick):
        rng = np.random.default_rng(1)
        n = len(build())
        a_nc, b_nc = rng.normal(size=(2, n, 3))
        rows = []
        for steps in lengths:
            atoms = build()
            dyn = ReversibleVerlet(atoms, 5 * units.fs, **FINE)
            start = (atoms.positions.copy(), atoms.get_momenta())
            t0 = time.perf_counter()
            dyn.run(steps)
            t1 = time.perf_counter()
            g = dyn.backpropagate(steps, a_nc, b_nc)
            t2 = time.perf_counter()
            exact = bool(np.array_equal(atoms.positions, start[0])
                         and np.array_equal(atoms.get_momenta(), start[1]))
            growth = max(np.abs(g.positions).max(), np.abs(g.momenta).max()) \
                / max(np.abs(a_nc).max(), np.abs(b_nc).max())
            directional = []
            for _ in range(directions):
                u_nc = rng.normal(size=(n, 3))
                for which, ours in (('x', g.positions), ('p', g.momenta)):
                    adjoint = float(np.vdot(ours, u_nc))
                    per_h = {}
                    for h in FD_H:
                        move = {'dx_nc' if which == 'x' else 'dp_nc': h * u_nc}
                        minus = {k: -v for k, v in move.items()}
                        fd = (_loss_run(build, steps, a_nc, b_nc, **move)
                              - _loss_run(build, steps, a_nc, b_nc, **minus)) \
                            / (2 * h)
                        per_h[repr(h)] = abs(fd - adjoint) / abs(adjoint)
                    directional.append({'variable': which, 'errors': per_h})
            rows.append({'steps': steps, 'growth': float(growth),
                         'exact_return': exact,
                         'forward_s': t1 - t0, 'backward_s': t2 - t1,
                         'directions': directional})
        results.append({'case': label, 'n_atoms': n, 'rows': rows})
    return results


def run(quick, figures):
    results = {'hvp': measure_hvp(quick), 'runs': measure_runs(quick)}
    plt = common.pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for row in results['hvp']:
        steps = [float(k) for k in row['errors']]
        left.loglog(steps, list(row['errors'].values()), 'o-',
                    label=row['case'])
    default = results['hvp'][0]['default_step']
    left.axvline(default, color='grey', ls=':', label='default step')
    left.set_xlabel('finite-difference step (Å)')
    left.set_ylabel('relative error of H v')
    left.set_title('Finite-difference Hessian-vector products')
    left.legend(fontsize=7)
    for case in results['runs']:
        steps = [r['steps'] for r in case['rows']]
        best = [max(min(d['errors'].values()) for d in r['directions'])
                for r in case['rows']]
        growth = [r['growth'] for r in case['rows']]
        line, = right.loglog(steps, best, 'o-', label=f"{case['case']}: error")
        right.loglog(steps, growth, 's--', color=line.get_color(),
                     label='gradient growth')
    right.set_xlabel('steps (5 fs)')
    right.set_title('backpropagate against whole-run finite differences')
    right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(figures / 'gradient_accuracy.png', dpi=120)
    plt.close(fig)
    return results


def render(results):
    hvp = results['hvp']
    steps = list(hvp[0]['errors'])
    lines = [
        'How accurate the gradients of `ReversibleVerlet.backpropagate` '
        'are (`benchmarks/gradient_accuracy.py`).',
        '',
        '![gradient accuracy](benchmarks/gradient_accuracy.png)',
        '',
        '### Finite-difference Hessian-vector products',
        '',
        'Largest component error over the largest component of the '
        'reference, for one random direction; the default step is '
        f"{hvp[0]['default_step']:g} Å. Reference: `analytic` is the "
        "calculator's exact product, `stencil` a fourth-order difference at "
        '1e-5 Å.',
        '',
        common.markdown_table(
            ['case', 'reference'] + [f'{float(s):g} Å' for s in steps],
            [[r['case'], r['reference']]
             + [f"{r['errors'][s]:.1e}" for s in steps] for r in hvp]),
        '',
        '### Whole-run gradients',
        '',
        'Linear loss `L = <a, x_T> + <b, p_T>` with random `a`, `b`; '
        'relative error of the directional derivative `<dL/dx0, u>` (and '
        'the same for `p0`) against central finite differences of the whole '
        'run with h = ' + ', '.join(f'{h:g}' for h in FD_H) + ' (Å, or amu '
        'Å / ASE time), for random `u`. "best h" is the smallest of the '
        'three errors, the largest over directions; "growth" the gradient '
        'growth over the run. Fine quanta (2^-44 Å, 2^-46), time step 5 fs.',
        '',
    ]
    for case in results['runs']:
        lines += [f"**{case['case']}** ({case['n_atoms']} atoms)", '']
        rows = []
        for r in case['rows']:
            per_h = {h: max(d['errors'][repr(h)] for d in r['directions'])
                     for h in FD_H}
            best = max(min(d['errors'].values()) for d in r['directions'])
            rows.append([r['steps'], f"{r['growth']:.3g}", f'{best:.1e}']
                        + [f'{per_h[h]:.1e}' for h in FD_H]
                        + ['yes' if r['exact_return'] else 'NO',
                           f"{r['backward_s'] / r['forward_s']:.2f}"])
        lines += [common.markdown_table(
            ['steps', 'growth', 'error, best h']
            + [f'error, h={h:g}' for h in FD_H]
            + ['back at start bit for bit', 'backward / forward time'],
            rows), '']
    worst_case, worst_row = max(
        ((case, r) for case in results['runs'] for r in case['rows']),
        key=lambda cr: max(min(d['errors'].values())
                           for d in cr[1]['directions']))
    worst = max(min(d['errors'].values()) for d in worst_row['directions'])
    per_h = [max(d['errors'][repr(h)] for d in worst_row['directions'])
             for h in FD_H]
    falls = ', '.join(f'{a / b:.0f}×' for a, b in zip(per_h, per_h[1:]))
    lines += [f"Largest error at the best h: {worst:.1e} ({worst_case['case']}, "
              f"{worst_row['steps']} steps, growth {worst_row['growth']:.3g}). "
              f'There, each 10× smaller h divides the error by {falls}: '
              'the finite differences\' truncation error (∝ h², growing '
              'with the curvature of the run map) still dominates the '
              'comparison, so it bounds the error of the adjoint from '
              'above only.']
    return '\n'.join(lines)
