"""Accuracy of the reversible adjoint's gradients.

1. ``FiniteDifferenceHVP(step)`` against the exact product (LennardJones)
   or a fourth-order stencil (EMT), over a sweep of steps.
2. ``backpropagate`` against central finite differences of whole
   ReversibleVerlet runs (fine quanta) along random directions, for runs
   of growing length, with the gradient's growth over the run.
"""

from __future__ import annotations

import common  # noqa: F401  (first: pins BLAS threads before numpy)

import time

import asap3
import numpy as np
from ase import units
from ase.calculators.emt import EMT

from ase_reversible import (FiniteDifferenceHVP, LennardJones,
                            ReversibleVerlet)
from ase_reversible.app.systems import (AR_EPSILON, AR_SIGMA, argon_cluster,
                                        copper_bulk, copper_cluster)

TIMESTEP_FS = 5.0
FINE = {'position_quantum': 2.0**-44, 'momentum_quantum': 2.0**-46,
        'energy_check': 0}
STEPS_FD = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6)
#: The step of the fourth-order reference stencil, Å.
STENCIL_STEP = 1e-5
FD_H = (1e-5, 1e-6, 1e-7)


def _hvp_cases():
    # Only the positions matter for a Hessian-vector product: the momenta
    # the builders draw are not used.
    def argon():
        atoms = argon_cluster(4, 60)
        atoms.rattle(0.1, seed=1)
        atoms.calc = LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA)
        return atoms

    def copper(calc):
        def build():
            atoms = copper_bulk((4, 4, 4), 300, seed=1, rattle=0.05)
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
    default_step = FiniteDifferenceHVP().step
    rows = []
    cases = _hvp_cases()[:2] if quick else _hvp_cases()
    for label, build, kind in cases:
        atoms = build()
        v_nc = np.random.default_rng(0).normal(size=(len(atoms), 3))
        reference_nc = (atoms.calc.hessian_vector_product(atoms, v_nc)
                        if kind == 'analytic'
                        else _stencil(atoms, v_nc, STENCIL_STEP))
        scale = np.abs(reference_nc).max()
        errors = {}
        for step in STEPS_FD:
            hv_nc = FiniteDifferenceHVP(step)(atoms, v_nc)
            errors[step] = float(np.abs(hv_nc - reference_nc).max() / scale)
        rows.append({'case': label, 'n_atoms': len(atoms), 'reference': kind,
                     'errors': {repr(k): v for k, v in errors.items()},
                     'default_step': default_step})
    return rows


def _run_cases(quick):
    def argon():
        atoms = argon_cluster(3, 60)
        atoms.calc = LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA)
        return atoms

    def copper():
        atoms = copper_cluster(2, 600)
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
    atoms = build()
    atoms.positions = atoms.positions + dx_nc
    atoms.set_momenta(atoms.get_momenta() + dp_nc)
    ReversibleVerlet(atoms, TIMESTEP_FS * units.fs, **FINE).run(steps)
    return float(np.vdot(a_nc, atoms.positions)
                 + np.vdot(b_nc, atoms.get_momenta()))


def measure_runs(quick):
    results = []
    for label, build, lengths, directions in _run_cases(quick):
        rng = np.random.default_rng(1)
        n = len(build())
        a_nc, b_nc = rng.normal(size=(2, n, 3))
        rows = []
        for steps in lengths:
            atoms = build()
            dyn = ReversibleVerlet(atoms, TIMESTEP_FS * units.fs, **FINE)
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


def run(quick):
    return {'hvp': measure_hvp(quick), 'runs': measure_runs(quick),
            'settings': {'timestep_fs': TIMESTEP_FS,
                         'position_quantum': FINE['position_quantum'],
                         'momentum_quantum': FINE['momentum_quantum'],
                         'stencil_step': STENCIL_STEP}}
