"""Keyframe control of a pendulum chain with the reversible adjoint.

The paper's optimisation example (J. Stam, "An Exact Bitwise Reversible
Integrator", section "Application: Reversible Adjoint / Neural ODEs"): a
chain pinned at one end swings under gravity, and its initial velocities
are chosen so that at time ``T`` it hits a target "S".

Each evaluation of the loss runs the chain forward with
:class:`~ase_reversible.ReversibleVerlet` and gets the gradient with
respect to the initial momenta from
:meth:`~ase_reversible.ReversibleVerlet.backpropagate`, which runs the
chain back to its start bit for bit while integrating the adjoint: no
trajectory is stored, whatever the number of steps.  SciPy's L-BFGS-B
does the rest.

Run ``python examples/keyframe_chain.py --out DIR`` (``--quick``: stop
after 20 iterations); it saves ``DIR/keyframe_chain.png``.

Units are ASE's: Å, amu, eV, and the ASE time unit (Å sqrt(amu/eV), about
10.18 fs).  The beads weigh 1 amu and the links are 1 Å, so gravity in
eV/(Å amu) is the acceleration in Å per time unit squared.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ase import units
from scipy.optimize import minimize

from ase_reversible import ReversibleVerlet
from ase_reversible.calculators import PendulumChain, make_chain
from ase_reversible import INFO_KEY


@dataclass(frozen=True)
class Setup:
    """The control problem.  Lengths Å, masses amu, times ASE units."""

    n_links: int = 10
    link_length: float = 1.0
    mass: float = 1.0
    #: Start pose, degrees from straight down towards +x.  From 30 to 60
    #: degrees L-BFGS-B gets below 0.01 Å²; from horizontal (90) this
    #: stiffer chain stalls near 70 Å² (a local minimum).
    start_angle: float = 45.0
    #: eV/Å².  The chain's fastest mode has an angular frequency below
    #: 2 sqrt(k/m) = 63 per time unit: 0.79 rad per step, ~8 steps per
    #: period (Verlet is stable up to 2 rad).  Stiff against the swing
    #: (~0.3 per time unit) and against the tensions: gravity stretches
    #: the top link by 1%, and in the optimised run every link is within
    #: 1.5% of its rest length at T.
    stiffness: float = 1000.0
    #: eV/(Å amu): the chain falls ~2 Å in T under gravity alone.
    gravity: float = 1.0
    timestep: float = 0.0125
    #: T = 2 time units (20 fs).  Much longer and the chaotic chain's loss
    #: gets too rugged for a local optimiser started from rest: with T = 3
    #: and 4 L-BFGS-B stalls at 33 and 77 Å² within 100 iterations.
    steps: int = 160
    #: How far round each of the S's two arcs turns, in units of pi: above
    #: 1 the ends curl in, as in a printed S.
    arc_turn: float = 1.25
    iterations: int = 100
    #: Quanta (powers of two) fixed for all evaluations, so that every
    #: evaluation runs on the same grid.  2**-40 Å and amu Å / time unit
    #: resolve 1e-12 and cover 8e3 in magnitude, far beyond this chain.
    position_quantum: float = 2.0**-40
    momentum_quantum: float = 2.0**-40


#: The smoke-test version: the same problem, stopped early, when the loss
#: is already ~1000 times lower than at rest.
QUICK = Setup(iterations=20)


def s_curve(n_links, link_length, arc_turn):
    """Target positions ``[n_links + 1, 3]`` (Å) on an "S" hanging from 0.

    Two circular arcs of ``n_links // 2`` links each, turning ``arc_turn *
    pi`` in opposite senses and joined where their tangents meet, so the
    curve is smooth.  The points sit on the arcs at chord distance
    ``link_length``: the target is a pose the chain can take with
    unstretched links, and its arc length matches the chain's.
    """
    if n_links % 2:
        raise ValueError(f'An S needs an even number of links, got {n_links}')
    half = n_links // 2
    turn = arc_turn * math.pi
    step = turn / half                       # angle per link
    radius = 0.5 * link_length / math.sin(0.5 * step)
    # Upper arc: anticlockwise over the top and down the left side, ending
    # at its lowest point; it starts (at the pin, the origin) at angle a0.
    a0 = 1.5 * math.pi - turn
    angle1 = a0 + step * np.arange(half + 1)
    centre1 = -radius * np.array([math.cos(a0), math.sin(a0)])
    upper = centre1 + radius * np.stack([np.cos(angle1), np.sin(angle1)], 1)
    # Lower arc: clockwise from its top (the junction) round the right.
    centre2 = upper[-1] - np.array([0.0, radius])
    angle2 = 0.5 * math.pi - step * np.arange(1, half + 1)
    lower = centre2 + radius * np.stack([np.cos(angle2), np.sin(angle2)], 1)
    xz = np.vstack([upper, lower])
    target_nc = np.zeros((n_links + 1, 3))
    target_nc[:, 0], target_nc[:, 2] = xz[:, 0], xz[:, 1]
    return target_nc


class Problem:
    """Loss and gradient of the keyframe match, for the optimiser.

    The controls ``u`` are the initial momenta of the free atoms (all but
    the pinned atom 0), x and z components, flattened:
    ``u.reshape(n_links, 2)`` is ``[n_links, 2]``, amu Å / time unit.
    """

    def __init__(self, setup: Setup):
        self.setup = setup
        s = setup
        self.atoms = make_chain(s.n_links, s.link_length, s.mass,
                                s.start_angle)
        self.atoms.calc = PendulumChain(stiffness=s.stiffness,
                                        rest_length=s.link_length,
                                        gravity=s.gravity)
        self.x0_nc = self.atoms.get_positions()
        self.target_nc = s_curve(s.n_links, s.link_length, s.arc_turn)
        self.evaluations = 0
        self._last = None  # (u bytes, fit loss) of the latest evaluation

    @property
    def size(self):
        return 2 * self.setup.n_links

    def momenta(self, u):
        """Initial momenta ``[n_atoms, 3]`` from the controls."""
        p_nc = np.zeros((self.setup.n_links + 1, 3))
        p_nc[1:, [0, 2]] = np.reshape(u, (-1, 2))
        return p_nc

    def start(self, u):
        """Put the chain at its start pose with momenta ``u``; the integrator.

        A new integrator per evaluation: the constructor takes the atoms'
        state as the anchor of reversal.  The energy check keeps its
        default: it never fires here, as Verlet's energy error stays near
        0.2% of the starting kinetic energy (its tolerance), even for
        three times the optimised controls.
        """
        s = self.setup
        # Every evaluation starts at t = 0: the restart record the last
        # run left in atoms.info would carry its time into this one.
        self.atoms.info.pop(INFO_KEY, None)
        self.atoms.set_positions(self.x0_nc, apply_constraint=False)
        self.atoms.set_momenta(self.momenta(u), apply_constraint=False)
        return ReversibleVerlet(self.atoms, s.timestep,
                                position_quantum=s.position_quantum,
                                momentum_quantum=s.momentum_quantum)

    def fit(self):
        """Loss at the atoms' current positions, Å², and dL/dx ``[n, 3]``."""
        r_nc = self.atoms.positions - self.target_nc
        return float(np.vdot(r_nc, r_nc)), 2.0 * r_nc

    def loss_and_gradient(self, u):
        """``L(u) = |x(T) - target|²`` (Å²) and ``dL/du``.

        No regulariser: there are as many controls as target coordinates
        (x and z of each free atom), so matching controls are isolated
        rather than a family to choose from.  A penalty ``0.5 w |u|²``
        (tried with w from 1e-4 to 1e-2 Å² per (amu Å / time unit)²) led
        to the same controls, |u| within 4%, and a worse fit after 100
        iterations.
        """
        u = np.asarray(u, dtype=float)
        dyn = self.start(u)
        dyn.run(self.setup.steps)
        loss, grad_x_nc = self.fit()
        grad = dyn.backpropagate(self.setup.steps, grad_x_nc)
        self.evaluations += 1
        self._last = (u.tobytes(), loss)
        return loss, grad.momenta[1:, [0, 2]].ravel()

    def fit_at(self, u):
        """The fit loss (Å²) at ``u``, from the latest evaluation if there."""
        if self._last is not None and self._last[0] == np.asarray(
                u, dtype=float).tobytes():
            return self._last[1]
        dyn = self.start(u)
        dyn.run(self.setup.steps)
        return self.fit()[0]


def optimise(problem):
    """L-BFGS-B from rest; returns the result and the fit per iteration."""
    u0 = np.zeros(problem.size)
    history = [problem.fit_at(u0)]
    result = minimize(problem.loss_and_gradient, u0, jac=True,
                      method='L-BFGS-B',
                      options={'maxiter': problem.setup.iterations},
                      callback=lambda xk: history.append(
                          problem.fit_at(xk)))
    return result, history


def final_run(problem, u, frames):
    """Forward with ``u`` recording ``frames`` poses, then back exactly.

    Returns the poses ``[frames, n_atoms, 3]``, their times, and whether
    the backpropagation left positions and momenta bitwise at the start.
    """
    steps = problem.setup.steps
    dyn = problem.start(u)
    start_x_nc = problem.atoms.get_positions()
    start_p_nc = problem.atoms.get_momenta()
    marks = set(np.linspace(0, steps, frames).round().astype(int).tolist())
    poses, times = [], []

    def record():
        if dyn.nsteps in marks:
            poses.append(problem.atoms.get_positions())
            times.append(dyn.get_time())

    dyn.attach(record, interval=1)
    dyn.run(steps)
    dyn.observers.clear()
    _, grad_x_nc = problem.fit()
    dyn.backpropagate(steps, grad_x_nc)
    exact = (np.array_equal(problem.atoms.positions, start_x_nc)
             and np.array_equal(problem.atoms.get_momenta(), start_p_nc))
    return np.array(poses), np.array(times), exact


def draw(path, problem, u, poses, times, history):
    """The frames (start with velocity arrows, target at T) and the loss."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    s = problem.setup
    target_nc = problem.target_nc
    v_nc = problem.momenta(u) / s.mass
    n = len(poses)
    rows = 2
    cols = -(-n // rows)
    # One box for all frames, fitted to everything drawn in any of them.
    scale = _arrow_scale(problem, v_nc)
    points = np.vstack([poses.reshape(-1, 3), target_nc,
                        poses[0] + scale * v_nc])
    lo = points[:, [0, 2]].min(axis=0) - 0.7
    hi = points[:, [0, 2]].max(axis=0) + 0.7
    box = 2.4 * (hi[0] - lo[0]) / (hi[1] - lo[1])  # inches per frame
    fig = plt.figure(figsize=(box * cols + 5.0, 2 * 2.4 + 0.6),
                     layout='constrained')
    grid = fig.add_gridspec(rows, cols + 1,
                            width_ratios=(box,) * cols + (4.6,))
    for k, (x_nc, t) in enumerate(zip(poses, times)):
        ax = fig.add_subplot(grid[k // cols, k % cols])
        if k == n - 1:
            ax.plot(target_nc[:, 0], target_nc[:, 2], 'o--',
                    color='tab:orange', ms=9, mfc='none', lw=1.5,
                    label='target "S"')
        ax.plot(x_nc[:, 0], x_nc[:, 2], 'o-', color='k', ms=4, lw=1.5)
        ax.plot([0], [0], 's', color='tab:blue', ms=7)
        if k == 0:
            ax.quiver(x_nc[:, 0], x_nc[:, 2], scale * v_nc[:, 0],
                      scale * v_nc[:, 2], color='red', angles='xy',
                      scale_units='xy', scale=1, width=0.012)
        ax.set_title(f't = {t / units.fs:.1f} fs'
                     + (' = T' if k == n - 1 else ''), fontsize=10)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect('equal')
        ax.set_xticks([])
        ax.set_yticks([])
        if k == n - 1:
            ax.legend(loc='upper right', fontsize=8)
    ax = fig.add_subplot(grid[:, cols])
    ax.semilogy(np.arange(len(history)), history, '.-')
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel('L-BFGS-B iteration')
    ax.set_ylabel('|x(T) - target|²  (Å²)')
    ax.grid(True, which='both', alpha=0.3)
    ax.set_title('loss at T per iteration', fontsize=10)
    fig.suptitle(f'A {s.n_links}-link pendulum chain (pinned at the blue '
                 'square, under gravity) whose initial velocities (red) '
                 'make it hit an "S" at time T')
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _arrow_scale(problem, v_nc):
    """Time (ASE units) that turns velocities into drawn arrows (Å)."""
    longest = float(np.sqrt((v_nc**2).sum(axis=1)).max())
    reach = problem.setup.n_links * problem.setup.link_length
    return 0.3 * reach / longest if longest > 0 else 0.0


def main(out_dir='.', quick=False) -> dict:
    """Optimise, draw, and report.

    Returns a dict with ``loss_initial`` and ``loss_final`` (Å², at rest
    and at the optimised controls), ``iterations``, ``evaluations``,
    ``picture`` (path of the PNG), ``exact_return`` (True if the final
    backpropagation left the chain bitwise at its start) and ``seconds``.
    """
    started = time.perf_counter()
    setup = QUICK if quick else Setup()
    problem = Problem(setup)
    result, history = optimise(problem)
    poses, times, exact = final_run(problem, result.x, frames=6)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    picture = out_dir / 'keyframe_chain.png'
    draw(picture, problem, result.x, poses, times, history)
    return {'loss_initial': history[0], 'loss_final': history[-1],
            'iterations': int(result.nit),
            'evaluations': problem.evaluations,
            'picture': str(picture), 'exact_return': bool(exact),
            'seconds': time.perf_counter() - started}


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='.', help='directory for the picture')
    parser.add_argument('--quick', action='store_true',
                        help='stop after 20 iterations (for smoke tests)')
    args = parser.parse_args()
    report = main(args.out, args.quick)
    print(f"loss {report['loss_initial']:.4g} -> {report['loss_final']:.4g} "
          f"Å² in {report['iterations']} iterations "
          f"({report['evaluations']} forward/backward runs), "
          f"{report['seconds']:.1f} s")
    print('back at the start bit for bit after the last backpropagate:',
          report['exact_return'])
    print('picture:', report['picture'])
