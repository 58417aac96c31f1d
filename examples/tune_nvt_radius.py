"""Tune a potential parameter so that a thermostatted cluster has a given size.

An Ar55 icosahedron (the package's :class:`~ase_reversible.LennardJones`,
argon's epsilon) is held at 30 K by :class:`~ase_reversible.ReversibleNose`.
Its size is the radius of gyration averaged over the frames of a 3 ps run
(every 10 steps after the first 100).  We ask which Lennard-Jones ``sigma``
gives a mean radius of ``TARGET`` Å, and find it by Newton's method on the
mean radius, whose derivative with respect to ``sigma`` comes from
:meth:`~ase_reversible.ReversibleNose.backpropagate`: the run is retraced
exactly, segment by segment, each frame adding its own gradient, the
thermostat's part of the gradient carried from one segment to the next
(``carry=``), and the potential parameter's gradient accumulated
(``parameters=('sigma',)``).  Nothing of the run is stored.

Every run starts from the same positions, the icosahedron built for
argon's sigma: with a larger sigma the cluster first swells and breathes,
which the picture shows.  The first derivative is checked against a
central finite difference of two more runs, and every retrace must end bit
for bit at the state the run started from.  The cut-offs are fixed
(``rc``, ``ro``): the calculator's default ``rc = 3 sigma`` would move
with ``sigma``, which the gradient does not follow.

Run it::

    python examples/tune_nvt_radius.py --out docs/images   # about 20 s
    python examples/tune_nvt_radius.py --out /tmp --quick  # about 5 s

It writes ``tune_nvt_radius.png`` and prints each iteration; :func:`main`
returns the numbers.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from ase import units
from ase.md.velocitydistribution import Stationary, ZeroRotation

from ase_reversible import LennardJones, ReversibleNose
from ase_reversible.app.systems import AR_EPSILON, AR_SIGMA, argon_cluster

TEMPERATURE_K = 30.0
TIMESTEP = 5 * units.fs
TDAMP = 250 * units.fs
#: Steps between sampled frames, and steps before the first one.
EVERY, LEAD = 10, 100
#: Mean radius of gyration asked for, Å (the argon sigma gives 6.12 Å).
TARGET = 6.30
#: Fixed cut-offs, Å: 3 and 2 times argon's sigma.
RC, RO = 10.2, 6.8


def radius(positions):
    """Radius of gyration (Å) and its gradient ``[n_atoms, 3]``."""
    d_nc = positions - positions.mean(axis=0)
    r = float(np.sqrt((d_nc**2).sum() / len(d_nc)))
    # The centre's own dependence drops out: the d_nc sum to zero.
    return r, d_nc / (len(d_nc) * r)


def cluster(sigma):
    atoms = argon_cluster(3, TEMPERATURE_K, seed=1)
    Stationary(atoms)
    ZeroRotation(atoms)
    atoms.calc = LennardJones(epsilon=AR_EPSILON, sigma=sigma, rc=RC, ro=RO)
    return atoms


def mean_radius(sigma, steps, gradient=False):
    """``(mean radius, d mean radius / d sigma or None, radii, exact)``:
    the mean over frames ``LEAD, LEAD + EVERY, ..., steps``; ``exact`` is
    whether the retrace ended bit for bit at the start."""
    atoms = cluster(sigma)
    dyn = ReversibleNose(atoms, TIMESTEP, TEMPERATURE_K, TDAMP)
    start = dyn.counts
    radii = []
    dyn.attach(lambda: radii.append(radius(atoms.positions)[0]),
               interval=EVERY)
    dyn.run(steps)
    frames = radii[LEAD // EVERY:]
    mean = float(np.mean(frames))
    if not gradient:
        return mean, None, radii, None
    # d(mean)/d(frame k's positions) = dR_k/dx / M, frame by frame back.
    weight = 1.0 / len(frames)
    grads, d_sigma, left = None, 0.0, steps
    while True:
        g_nc = radius(atoms.positions)[1] * weight
        back = EVERY if left - EVERY >= LEAD else left
        if grads is None:
            grads = dyn.backpropagate(back, g_nc, None,
                                      parameters=('sigma',))
        else:
            grads = dyn.backpropagate(back, grads.positions + g_nc,
                                      grads.momenta, parameters=('sigma',),
                                      carry=grads)
        d_sigma += grads.parameters['sigma']
        left -= back
        if left == 0:
            break
    exact = all(np.array_equal(c, start[k]) for k, c in dyn.counts.items())
    return mean, d_sigma, radii, exact


def main(out_dir='.', quick=False) -> dict:
    """Run the tuning; return the numbers.

    Returns a dict: ``sigmas`` and ``mean_radii`` (Å) of each iteration,
    ``derivative`` and ``finite_difference`` (d mean radius / d sigma at
    argon's sigma, from the retrace and from two more runs),
    ``loss_initial``, ``loss_final`` ((mean radius - target)**2, Å**2),
    ``iterations``, ``exact_return`` (every retrace ended bitwise at its
    start), ``picture`` and ``seconds``.
    """
    started = time.perf_counter()
    steps = 300 if quick else 600
    iterations = 2 if quick else 4
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    sigma, sigmas, means, traces, exact = AR_SIGMA, [], [], [], True
    derivative = None
    for i in range(iterations):
        mean, slope, radii, came_back = mean_radius(sigma, steps, True)
        exact &= came_back
        sigmas.append(sigma)
        means.append(mean)
        traces.append(radii)
        print(f'iteration {i}: sigma {sigma:.5f} Å  mean radius '
              f'{mean:.4f} Å  d/dsigma {slope:.4f}  retrace exact '
              f'{came_back}')
        if derivative is None:
            derivative = slope
        sigma = sigma - (mean - TARGET) / slope
    h = 1e-4
    finite_difference = (mean_radius(AR_SIGMA + h, steps)[0]
                         - mean_radius(AR_SIGMA - h, steps)[0]) / (2 * h)
    print(f'd mean radius / d sigma at {AR_SIGMA} Å: {derivative:.6f} '
          f'(retrace), {finite_difference:.6f} (finite difference)')
    picture = out / 'tune_nvt_radius.png'
    plot(picture, traces, sigmas, steps)
    return {'sigmas': sigmas, 'mean_radii': means,
            'derivative': derivative, 'finite_difference': finite_difference,
            'loss_initial': (means[0] - TARGET)**2,
            'loss_final': (means[-1] - TARGET)**2,
            'iterations': iterations, 'exact_return': bool(exact),
            'picture': str(picture),
            'seconds': time.perf_counter() - started}


def plot(path, traces, sigmas, steps):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    t_ps = np.arange(0, steps + 1, EVERY) * TIMESTEP / (1000 * units.fs)
    for i, (radii, sigma) in enumerate(zip(traces, sigmas)):
        ax.plot(t_ps[:len(radii)], radii, color=f'C{i}', lw=1.2,
                label=f'iteration {i}: sigma = {sigma:.4f} Å')
        ax.axhline(np.mean(radii[LEAD // EVERY:]), color=f'C{i}', lw=0.6,
                   ls=':')
    ax.axhline(TARGET, color='k', lw=1, ls='--', label='target mean')
    ax.axvspan(0, LEAD * TIMESTEP / (1000 * units.fs), color='0.9')
    ax.set_xlabel('virtual time (ps)')
    ax.set_ylabel('radius of gyration (Å)')
    ax.set_title(f'Ar55 at {TEMPERATURE_K:g} K (ReversibleNose): sigma tuned '
                 'by gradients through the run', fontsize=10)
    ax.legend(fontsize=8, loc='lower right')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', default='.', help='folder for the picture')
    parser.add_argument('--quick', action='store_true',
                        help='shorter runs, two iterations')
    args = parser.parse_args()
    result = main(args.out, args.quick)
    print(f'{result["seconds"]:.1f} s; picture {result["picture"]}')
