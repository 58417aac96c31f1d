"""Fit a pair potential to a dynamical target, through exact reversible
molecular dynamics: the velocity autocorrelation function (VACF), which
reweighting sampled configurations cannot give.

The system, the reference and the Lennard-Jones student are
``fit_rdf.py``'s (beside this file, imported from it).  The student's ε and
σ are fitted to the reference's normalised VACF, measured on NVE windows
(``ReversibleVerlet``) started from the student's own NVT run
(``ReversibleLangevin``); one retrace per window hands each sample its
dL/dp through ``loss=``.  The window's start is taken as given (the
gradient does not reach into the thermostatted run that made it).

Run it::

    python examples/fit_vacf.py --out DIR            # 256 atoms
    python examples/fit_vacf.py --out DIR --quick    # 32 atoms, < 30 s

It prints the loss per epoch and writes ``DIR/fit_vacf.png`` (the VACF
before and after against the target, the loss per epoch) and
``DIR/fit_vacf.json``; :func:`fit_vacf` returns them.  The picture in
docs/images is the full run's.
"""

from __future__ import annotations

import os
import time

import numpy as np
from ase import units

from ase_reversible import LennardJones, ReversibleLangevin, ReversibleVerlet
from ase_reversible.core.record import INFO_KEY
from fit_rdf import (EPSILON, FRICTION, FULL, QUICK, SEED, SIGMA,
                     TEMPERATURE_K, TIMESTEP, LJStudent, command_line,
                     finish, liquid_argon)


#: NVT steps between windows (the student's own thermostatted run, which
#: makes the next window's start), windows in the target, epochs, and the
#: factor on Adam's learning rate after each epoch (at a constant rate the
#: full run reached σ = 3.41 Å in 9 epochs, then overshot to 3.30 Å and
#: oscillated: one window per epoch is a noisy gradient; with 0.85 the
#: steps summed to too little and it stopped at 3.49 Å).
VACF_FULL = dict(window=160, every=8, between=200, target_windows=12,
                 epochs=20, decay=0.92)
VACF_QUICK = dict(window=80, every=8, between=100, target_windows=3,
                  epochs=3, decay=0.92)


def normalised_vacf(p0_nc, p_nc, m_n1):
    """``<v(0) . v(t)> / <v(0) . v(0)>`` over the atoms."""
    return float(np.sum(p0_nc * p_nc / m_n1**2) / np.sum((p0_nc / m_n1)**2))


def vacf_window(atoms, calc, names, steps, every, target_k=None):
    """An NVE window (``ReversibleVerlet``) from the atoms' state: the
    normalised VACF at every ``every`` steps and, with ``target_k``, the
    loss ``sum_k (vacf_k - target_k)²`` and its dL/dθ by one retrace that
    hands each sample its dL/dp (``loss=``).

    The window's start is taken as given: the gradient is that of the NVE
    window, not of the thermostatted run that made its start.  Returns
    ``(vacf_k, loss, dL/dθ, exact)``; the atoms end at the window's start.
    """
    atoms.calc = calc
    atoms.info.pop(INFO_KEY, None)
    dyn = ReversibleVerlet(atoms, TIMESTEP)
    x0_nc, p0_nc = atoms.positions.copy(), atoms.get_momenta()
    m_n1 = atoms.get_masses()[:, None]
    vacf_k = [1.0]
    for _ in range(steps // every):
        dyn.run(every)
        vacf_k.append(normalised_vacf(p0_nc, atoms.get_momenta(), m_n1))
    vacf_k = np.array(vacf_k)
    if target_k is None:
        dyn.reverse()
        dyn.run(steps)
        return vacf_k, None, None, np.array_equal(atoms.positions, x0_nc)
    miss_k = vacf_k - target_k
    loss = float(np.sum(miss_k**2))
    # d vacf_k / d p_k; the denominator is the start's, fixed here.
    dv_nc = p0_nc / m_n1**2 / np.sum((p0_nc / m_n1)**2)

    def loss_point(state, k):
        return None, 2 * miss_k[k // every] * dv_nc

    grads = dyn.backpropagate(steps, parameters=names, loss=loss_point,
                              every=every)
    exact = (np.array_equal(atoms.positions, x0_nc)
             and np.array_equal(atoms.get_momenta(), p0_nc))
    if not exact:
        raise RuntimeError('The retrace did not end bit for bit at the '
                           "window's start: this is a bug of ase_reversible.")
    return vacf_k, loss, grads.parameters, exact


def thermostatted(atoms, calc, steps, seed):
    """``steps`` NVT steps with ``calc`` (the start of the next window)."""
    atoms.calc = calc
    atoms.info.pop(INFO_KEY, None)
    ReversibleLangevin(atoms, TIMESTEP, TEMPERATURE_K, FRICTION,
                       seed=seed).run(steps)


def fit_vacf(out_dir='.', quick=False, report=print):
    """Fit the LJ student's ε and σ to the reference's VACF (a dynamical
    observable: reweighting configurations cannot give it).  Returns the
    numbers and writes ``fit_vacf.png``."""
    import torch
    torch.set_num_threads(1)
    tic = time.perf_counter()
    size, v = (QUICK, VACF_QUICK) if quick else (FULL, VACF_FULL)
    atoms = liquid_argon(size.repeat)
    reference = LennardJones(epsilon=EPSILON, sigma=SIGMA)
    thermostatted(atoms, reference, size.equilibrate, SEED)
    target_k = 0
    for k in range(v['target_windows']):
        target_k = target_k + vacf_window(atoms, reference, (), v['window'],
                                          v['every'])[0]
        thermostatted(atoms, reference, v['between'], SEED + 1000 + k)
    target_k = target_k / v['target_windows']
    report(f'target VACF: {v["target_windows"]} NVE windows of '
           f'{v["window"]} steps ({time.perf_counter() - tic:.0f} s)')
    student = LJStudent(learning_rate=size.learning_rate, decay=v['decay'])
    before = student.summary()
    losses, exact, first_k, last_k = [], [], None, None
    for k in range(v['epochs'] + 1):
        calc = student.calculator()
        thermostatted(atoms, calc, v['between'], SEED + 2000 + k)
        vacf_k, loss, grads, ok = vacf_window(
            atoms, calc, student.names, v['window'], v['every'], target_k)
        losses.append(loss)
        exact.append(ok)
        first_k = vacf_k if first_k is None else first_k
        last_k = vacf_k
        report(f'  epoch {k:3d}  VACF loss {loss:.4g}  back at the start '
               f'bit for bit: {"yes" if ok else "NO"}  '
               f'({student.describe()})')
        if k < v['epochs']:
            student.step(grads)
    result = {
        'atoms': len(atoms), 'epochs': v['epochs'], 'window': v['window'],
        'every': v['every'], 'time_fs': (np.arange(len(target_k))
                                         * v['every'] * TIMESTEP
                                         / units.fs).tolist(),
        'target': target_k.tolist(), 'vacf_initial': first_k.tolist(),
        'vacf_final': last_k.tolist(), 'loss_per_epoch': losses,
        'loss_initial': losses[0], 'loss_final': losses[-1],
        'exact_return': all(exact), 'exact_returns': sum(exact),
        'iterations': v['epochs'],
        'sigma_initial': before['sigma'], 'epsilon_initial': before['epsilon'],
        'sigma_final': student.summary()['sigma'],
        'epsilon_final': student.summary()['epsilon'],
    }
    os.makedirs(out_dir, exist_ok=True)
    return finish(result, out_dir, 'fit_vacf', _plot_vacf, tic)


def _plot_vacf(result):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (ax_c, ax_l) = plt.subplots(1, 2, figsize=(9, 3.6),
                                     layout='constrained')
    t = result['time_fs']
    ax_c.axhline(0, color='0.8', lw=0.8)
    ax_c.plot(t, result['target'], 'k-', lw=2, label='target (reference LJ)')
    ax_c.plot(t, result['vacf_initial'], '--', color='tab:red',
              label=f'student, σ = {result["sigma_initial"]:.3f} Å')
    ax_c.plot(t, result['vacf_final'], '-', color='tab:blue',
              label=f'after {result["epochs"]} epochs, σ = '
                    f'{result["sigma_final"]:.3f} Å')
    ax_c.set_xlabel('t (fs)')
    ax_c.set_ylabel('normalised VACF')
    ax_c.legend(fontsize=8)
    ax_l.semilogy(result['loss_per_epoch'], 'o-', ms=3)
    ax_l.set_xlabel('epoch')
    ax_l.set_ylabel('VACF loss')
    fig.suptitle(f'{result["atoms"]} argon atoms: LJ student fitted to the '
                 'velocity autocorrelation of NVE windows (ReversibleVerlet) '
                 'from its own NVT run', fontsize=9)
    fig.savefig(result['picture'], dpi=90)
    plt.close(fig)


if __name__ == '__main__':
    args = command_line(__doc__).parse_args()
    r = fit_vacf(args.out, args.quick)
    print(f'VACF loss {r["loss_initial"]:.4g} -> {r["loss_final"]:.4g}; '
          f'σ {r["sigma_initial"]:.3f} -> {r["sigma_final"]:.3f} Å; '
          f'{r["exact_returns"]} of {r["epochs"] + 1} retraces back bit '
          f'for bit; {r["seconds"]:.0f} s; {r["picture"]}')
