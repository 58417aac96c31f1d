"""Steer an argon cluster to a target by choosing its initial momenta.

An Ar13 icosahedron (the package's :class:`~ase_reversible.LennardJones`,
argon parameters) starts at rest in its relaxed shape.  We look for the
initial momenta that bring it, after ``STEPS`` steps of 5 fs (2 ps), onto a
*target*: the same cluster turned by 90 degrees about the viewing axis and
moved 6 Å to the right.  The loss is the mean squared distance of the
atoms from their targets at the end, and its gradient with respect to the
initial momenta comes from :meth:`ReversibleVerlet.backpropagate`, which
retraces the run exactly instead of storing it.  L-BFGS-B uses it to
optimise the 39 momenta.

Why this target.  A rigid turn plus a shift is a configuration the cluster
can actually reach: it is the start's own minimum-energy shape, so nothing
has to be torn apart, and getting there costs mostly translational and
rotational energy (0.24 + 0.15 eV, against a binding energy of 0.46 eV).
But the obvious guess does not reach it: the free-flight momenta
``m (target - start) / T``, exact without forces, send the atoms along
straight chords that cut through the cluster, and the interactions throw
them off by 1.7 Å RMS (the "before" panel of the picture).  Even the
rigid turn-and-shift momenta miss by 0.2 Å, stretched by the centrifugal
force.  A turn about the viewing axis is also easy to see: each atom is
coloured by its starting azimuth, so the colour wheel visibly turns.

Why no kinetic-energy penalty by default.  The target is reachable and
the problem is square (39 momenta for 39 coordinates), so the minimum is
generically isolated and needs no regulariser to be unique, and the
answer found without one is already physical: 0.425 eV of kinetic energy
against 0.380 eV for rigid turn-and-shift momenta, the difference being
internal motion that cancels the centrifugal stretching (0.03 eV, the
kinetic energy of ~20 K over the 33 internal degrees of freedom, colder
than the ~35 K at which Ar13 melts).  A penalty can only trade the hit
for energy, and the trade is poor here: with ``kinetic_weight=0.1``
(Å²/eV) the optimum carries 0.422 eV and misses by 0.012 Å RMS instead
of 0.0005 Å.  The option is there for targets that cannot be reached
exactly, where nothing else stops the optimiser from buying small
improvements of the miss with large amounts of energy.

Run it::

    python examples/steer_argon.py --out docs/images    # ~12 s of CPU
    python examples/steer_argon.py --out /tmp --quick    # ~3 s of CPU

It writes ``steer_argon.png`` and prints a short report; :func:`main`
returns the numbers.  Needs scipy and matplotlib besides the package.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np
from ase import units
from ase.cluster import Icosahedron
from ase.optimize import BFGS

from ase_reversible import LennardJones, ReversibleVerlet
from ase_reversible import INFO_KEY

#: Argon, eV and Å.
EPSILON, SIGMA = 0.0104, 3.4
TIMESTEP = 5 * units.fs
#: Steps to the target (2 ps).
STEPS = 400
#: L-BFGS-B iterations: full run, then ``quick``.  The quick run solves the
#: same problem, only stops early: halving T instead would make it a
#: harder one (the turn and shift in 1 ps take four times the energy, the
#: cluster deforms, and L-BFGS-B converges to a local minimum with a 1.2 Å
#: RMS miss).
ITERATIONS, QUICK_ITERATIONS = 30, 4
#: The target: turned by this angle about z (the viewing axis), then moved.
TURN_DEGREES = 90.0
SHIFT_C = np.array([6.0, 0.0, 0.0])
#: Orientation of the icosahedron (rotations about x, then y, degrees),
#: chosen so that no two of the 13 atoms hide each other when viewed
#: along z.
TILT_DEGREES = (45.0, 35.0)

#: Bound on every momentum component the optimiser may try, amu Å / ASE
#: time: 0.8 eV per component, ~70 times the kinetic energy per atom of
#: the solution.  Bounding the search is what makes one fixed grid safe
#: for every trial point (see the quanta below).
MOMENTUM_BOUND = 8.0
#: Fixed quanta, the same for every evaluation, so that every forward run
#: lives on the same grid and the loss is a deterministic function of the
#: initial momenta.  With all momentum components within MOMENTUM_BOUND the
#: total energy is below 3 * 13 * 0.8 = 31 eV, so no atom's momentum can
#: exceed sqrt(2 m 32 eV) ~ 51 and no atom can travel more than ~250 Å in
#: 2 ps.  2**-40 gives ranges of +-8192 (Å, and amu Å / ASE time), more
#: than twice both, at a resolution (1e-12) far below anything the picture
#: or the loss can see.
POSITION_QUANTUM = 2.0**-40
MOMENTUM_QUANTUM = 2.0**-40


def make_cluster():
    """Relaxed Ar13 icosahedron at rest, centre of mass at the origin.

    Relaxed because the ideal icosahedron (lattice constant 5.26 Å) is not
    quite at the minimum of the cut-off potential: left as it is, it would
    breathe, and the breathing would be part of what the momenta must
    steer.  Relaxed, the start and the target (its rigid image) are at
    rest.
    """
    atoms = Icosahedron('Ar', 2, latticeconstant=5.26)
    atoms.positions -= atoms.get_center_of_mass()
    tilt_cc = (_rotation([0.0, 1.0, 0.0], math.radians(TILT_DEGREES[1]))
               @ _rotation([1.0, 0.0, 0.0], math.radians(TILT_DEGREES[0])))
    atoms.positions = atoms.positions @ tilt_cc.T
    atoms.calc = LennardJones(epsilon=EPSILON, sigma=SIGMA)
    BFGS(atoms, logfile=None).run(fmax=1e-5)
    atoms.positions -= atoms.get_center_of_mass()
    atoms.set_momenta(np.zeros((len(atoms), 3)))
    return atoms


def target_positions(x_nc):
    """The start turned by TURN_DEGREES about z through its centre, moved."""
    turn_cc = _rotation([0.0, 0.0, 1.0], math.radians(TURN_DEGREES))
    centre_c = x_nc.mean(axis=0)
    return (x_nc - centre_c) @ turn_cc.T + centre_c + SHIFT_C


class Steering:
    """Loss and gradient as a function of the flattened initial momenta.

    Each call puts the cluster at its start with the given momenta, runs
    ``steps`` steps forward, evaluates the loss and runs the adjoint back
    through the same steps.  Calls are independent: every one constructs
    its own integrator on the same fixed grid, so the same momenta give
    the same loss and gradient bit for bit, and a repeated call (L-BFGS-B
    starts by evaluating the point we just drew) is answered from memory.

    Parameters
    ----------
    atoms : ase.Atoms
        The cluster, at its start, with the calculator attached.
    target_nc : numpy.ndarray ``[n_atoms, 3]``
        Target positions at the end, Å.
    steps : int
        Steps of TIMESTEP from the start to the target.
    kinetic_weight : float
        Å²/eV: weight of the initial kinetic energy in the loss.
    record_every : int
        Keep the positions every this many steps of the forward run, for
        the picture.

    Attributes
    ----------
    evaluations : int
        Forward runs + backpropagates so far.
    exact_returns : int
        Evaluations after which the atoms were back at the start bit for
        bit.
    last_exact_return : bool
        Whether the last backpropagate ended bit for bit at the start.
    last : dict
        The last evaluation: ``loss``, ``msd`` (Å²), ``kinetic`` (eV, at
        t = 0), ``p0_nc`` (the initial momenta as snapped to the grid),
        ``x_end_nc`` and ``path_tnc`` ``[frames, n_atoms, 3]`` (Å).
    """

    def __init__(self, atoms, target_nc, steps, kinetic_weight=0.0,
                 record_every=4):
        self.atoms = atoms
        self.x0_nc = atoms.positions.copy()
        self.target_nc = np.asarray(target_nc, dtype=float)
        self.m_n1 = atoms.get_masses()[:, None]
        self.steps = steps
        self.kinetic_weight = float(kinetic_weight)
        self.evaluations = self.exact_returns = 0
        self.last_exact_return = False
        self.record_every = record_every
        self.last = {}
        self._memory = (None, None)  # (momenta bytes, (loss, gradient))

    def __call__(self, p_flat):
        """``(loss, dloss/dp0 flattened)``; loss in Å²."""
        key = np.asarray(p_flat, dtype=float).tobytes()
        if key == self._memory[0]:
            loss, grad_flat = self._memory[1]
            return loss, grad_flat.copy()
        atoms = self.atoms
        atoms.positions[:] = self.x0_nc
        atoms.set_momenta(np.reshape(p_flat, self.x0_nc.shape))
        atoms.info.pop(INFO_KEY, None)  # a new run, not a restart
        # energy_check=0: the line search tries momenta far hotter than the
        # answer, whose runs may be inaccurate; such a run is still an
        # exact, reversible map with an exact gradient, and its large loss
        # is what tells L-BFGS-B to step back.  The check would raise
        # UnstableIntegrationError instead and end the optimisation.
        dyn = ReversibleVerlet(atoms, TIMESTEP,
                               position_quantum=POSITION_QUANTUM,
                               momentum_quantum=MOMENTUM_QUANTUM,
                               energy_check=0)
        # The constructor snapped the state to the grid: this is the exact
        # start the forward run leaves and the retrace must come back to.
        x_start_nc = atoms.positions.copy()
        p_start_nc = atoms.get_momenta()
        path = []
        dyn.attach(lambda: path.append(atoms.positions.copy()),
                   interval=self.record_every)
        dyn.run(self.steps)
        dyn.observers.clear()
        x_end_nc = atoms.positions.copy()
        miss_nc = x_end_nc - self.target_nc
        n = len(atoms)
        msd = float(np.vdot(miss_nc, miss_nc)) / n
        kinetic = float(np.sum(p_start_nc**2 / (2 * self.m_n1)))
        loss = msd + self.kinetic_weight * kinetic
        grad = dyn.backpropagate(self.steps, 2 * miss_nc / n)
        # The penalty depends on the initial momenta directly: its
        # derivative is added to the one carried back through the run.
        grad_p_nc = grad.momenta + self.kinetic_weight * p_start_nc / self.m_n1
        exact = (np.array_equal(atoms.positions, x_start_nc)
                 and np.array_equal(atoms.get_momenta(), p_start_nc))
        self.evaluations += 1
        self.exact_returns += exact
        self.last_exact_return = exact
        self.last = {'loss': loss, 'msd': msd, 'kinetic': kinetic,
                     'p0_nc': p_start_nc, 'x_end_nc': x_end_nc,
                     'path_tnc': np.array(path)}
        self._memory = (key, (loss, grad_p_nc.ravel()))
        return loss, grad_p_nc.ravel().copy()


def free_flight_momenta(steering):
    """``m (target - start) / T`` ``[n_atoms, 3]``: exact without forces."""
    return (steering.m_n1 * (steering.target_nc - steering.x0_nc)
            / (steering.steps * TIMESTEP))


def optimise(steering, p_nc, iterations):
    """L-BFGS-B from ``p_nc``; returns (result, loss per iteration).

    The losses start with that of ``p_nc`` (iteration 0).
    """
    from scipy.optimize import minimize
    losses = [steering(p_nc.ravel())[0]]

    def record(intermediate_result):
        losses.append(float(intermediate_result.fun))

    result = minimize(steering, p_nc.ravel(), jac=True, method='L-BFGS-B',
                      bounds=[(-MOMENTUM_BOUND, MOMENTUM_BOUND)] * p_nc.size,
                      callback=record, options={'maxiter': iterations})
    return result, np.array(losses)


def main(out_dir='.', quick=False, kinetic_weight=0.0):
    """Optimise the initial momenta, save the picture, return the numbers.

    Parameters
    ----------
    out_dir : str
        Where ``steer_argon.png`` goes (created if missing).
    quick : bool
        A cheaper run for smoke tests: QUICK_ITERATIONS iterations instead
        of ITERATIONS.
    kinetic_weight : float
        Å²/eV, weight of the initial kinetic energy in the loss (see the
        module docstring for why it is 0 by default).

    Returns
    -------
    dict
        ``loss_initial``, ``loss_final`` (Å²), ``rms_miss_initial``,
        ``rms_miss_final`` (Å), ``kinetic_energy_optimised`` (eV, of the
        optimised initial momenta), ``iterations``, ``evaluations``,
        ``loss_per_iteration``, ``picture`` (path), ``exact_return`` (the
        last retrace ended bit for bit at the start), ``exact_returns``
        (of ``evaluations``), ``seconds`` (wall time of the whole call),
        ``steps``.
    """
    tic = time.perf_counter()
    steps = STEPS
    iterations = QUICK_ITERATIONS if quick else ITERATIONS
    atoms = make_cluster()
    x0_nc = atoms.positions.copy()
    target_nc = target_positions(x0_nc)
    steering = Steering(atoms, target_nc, steps, kinetic_weight,
                        record_every=max(1, steps // 100))

    p_guess_nc = free_flight_momenta(steering)
    steering(p_guess_nc.ravel())
    before = steering.last
    result, losses = optimise(steering, p_guess_nc, iterations)
    # Usually L-BFGS-B's last evaluation is its answer, and this is
    # answered from memory; if not, the answer is run again.  Either way
    # steering.last describes result.x and its backpropagate was the last.
    steering(result.x)
    after = steering.last

    os.makedirs(out_dir, exist_ok=True)
    picture = os.path.join(out_dir, 'steer_argon.png')
    _plot(picture, x0_nc, steering.m_n1, target_nc, before, after, losses,
          steps)
    return {
        'loss_initial': float(losses[0]),
        'loss_final': float(after['loss']),
        'rms_miss_initial': math.sqrt(before['msd']),
        'rms_miss_final': math.sqrt(after['msd']),
        'kinetic_energy_optimised': after['kinetic'],
        'iterations': int(result.nit),
        'evaluations': steering.evaluations,
        'loss_per_iteration': losses.tolist(),
        'picture': picture,
        'exact_return': bool(steering.last_exact_return),
        'exact_returns': steering.exact_returns,
        'steps': steps,
        'seconds': time.perf_counter() - tic,
    }


# -- picture ------------------------------------------------------------------

#: Drawn radius of an atom, Å: smaller than argon's (~1.9 Å) so that the
#: projected cluster stays readable.
ATOM_RADIUS = 0.75


def _plot(path, x0_nc, m_n1, target_nc, before, after, losses, steps):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import NullFormatter
    from matplotlib.patches import Circle

    colours = _atom_colours(x0_nc)
    t_ps = steps * TIMESTEP / (1000 * units.fs)
    everything = np.concatenate([x0_nc, target_nc, before['x_end_nc'],
                                 after['x_end_nc'],
                                 before['path_tnc'].reshape(-1, 3),
                                 after['path_tnc'].reshape(-1, 3)])
    pad = ATOM_RADIUS + 0.6
    lo_c, hi_c = everything.min(axis=0) - pad, everything.max(axis=0) + pad

    fig = plt.figure(figsize=(13.0, 5.9), layout='constrained')
    grid = fig.add_gridspec(2, 4, height_ratios=(1.0, 0.72))
    panels = [fig.add_subplot(grid[0, k]) for k in range(4)]
    loss_ax = fig.add_subplot(grid[1, :])

    def frame(ax, title):
        ax.set_xlim(lo_c[0], hi_c[0])
        ax.set_ylim(lo_c[1], hi_c[1])
        ax.set_aspect('equal')
        ax.set_title(title, fontsize=9.5)
        ax.set_xlabel('x (Å)', fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(color='0.92', lw=0.6)
        ax.set_axisbelow(True)

    def atoms_at(ax, x_nc, hollow=False, alpha=1.0):
        # Back to front, so that nearer atoms cover farther ones.
        for i in np.argsort(x_nc[:, 2]):
            if hollow:
                patch = Circle(x_nc[i, :2], ATOM_RADIUS, fill=False,
                               ec=colours[i], lw=1.3, ls=(0, (2, 1.5)),
                               alpha=alpha, zorder=2)
            else:
                patch = Circle(x_nc[i, :2], ATOM_RADIUS, fc=colours[i],
                               ec='0.15', lw=0.7, alpha=alpha, zorder=3)
            ax.add_patch(patch)

    def paths(ax, path_tnc, x_end_nc):
        for i in range(path_tnc.shape[1]):
            xy = np.vstack([x0_nc[None, i, :2], path_tnc[:, i, :2],
                            x_end_nc[None, i, :2]])
            ax.plot(xy[:, 0], xy[:, 1], color=colours[i], lw=1.0,
                    alpha=0.6, zorder=1)

    def arrows(ax, p_nc, colour, width):
        # Drawn as the distance the atom would fly freely in 35% of T.
        d_nc = 0.35 * steps * TIMESTEP * p_nc / m_n1
        ax.quiver(x0_nc[:, 0], x0_nc[:, 1], d_nc[:, 0], d_nc[:, 1],
                  angles='xy', scale_units='xy', scale=1, color=colour,
                  width=width, zorder=4)

    ax = panels[0]
    frame(ax, 'start, t = 0 (relaxed Ar13)\narrows: momenta, grey before, '
          'black after')
    atoms_at(ax, x0_nc)
    arrows(ax, before['p0_nc'], '0.55', 0.006)
    arrows(ax, after['p0_nc'], '0.05', 0.006)
    ax.set_ylabel('y (Å)', fontsize=9)

    ax = panels[1]
    frame(ax, f'target at t = {t_ps:g} ps: the start turned\n'
          f'{TURN_DEGREES:g}° about z (view axis), moved {SHIFT_C[0]:g} Å')
    atoms_at(ax, x0_nc, alpha=0.15)
    atoms_at(ax, target_nc)

    for ax, run, title in (
            (panels[2], before, 'before: free-flight momenta\n'
             'm (target − start) / T'),
            (panels[3], after, 'after: optimised momenta\n'
             f'{len(losses) - 1} L-BFGS-B iterations')):
        frame(ax, f'{title}, at t = {t_ps:g} ps')
        paths(ax, run['path_tnc'], run['x_end_nc'])
        atoms_at(ax, target_nc, hollow=True)
        atoms_at(ax, run['x_end_nc'], alpha=0.95)
        ax.text(0.03, 0.04, f'RMS miss {math.sqrt(run["msd"]):.2g} Å',
                transform=ax.transAxes, fontsize=9,
                bbox={'fc': 'white', 'ec': '0.8', 'boxstyle': 'round'})
    panels[2].legend(
        handles=[Line2D([], [], color='0.4', lw=1.0, label='paths'),
                 Line2D([], [], ls='none', marker='o', ms=9, mfc='none',
                        mec='0.3', label='target')],
        loc='upper left', fontsize=8, framealpha=0.9)

    iterations_i = np.arange(len(losses))
    loss_ax.semilogy(iterations_i, losses, 'o-', color='tab:blue', ms=4,
                     lw=1.5)
    loss_ax.set_xlabel('L-BFGS-B iteration (gradients by '
                       'ReversibleVerlet.backpropagate)', fontsize=9)
    loss_ax.set_ylabel('loss (Å²)', fontsize=9)
    loss_ax.set_title('loss: mean squared distance to the target at t = '
                      f'{t_ps:g} ps', fontsize=10)
    loss_ax.grid(which='major', color='0.88', lw=0.6)
    loss_ax.grid(which='minor', axis='y', color='0.95', lw=0.4)
    loss_ax.set_xlim(-0.5, len(losses) - 0.5)
    loss_ax.tick_params(labelsize=8)
    rms_ax = loss_ax.secondary_yaxis(
        'right', functions=(lambda v: np.sqrt(np.maximum(v, 0)),
                            lambda r: np.square(r)))
    rms_ax.set_ylabel('RMS miss (Å)', fontsize=9)
    rms_ax.tick_params(labelsize=8)
    for axis in (loss_ax.yaxis, rms_ax.yaxis):
        axis.set_minor_formatter(NullFormatter())

    fig.suptitle(f'Steering Ar{len(x0_nc)} (Lennard-Jones argon) by its '
                 f'initial momenta: {steps} steps of '
                 f'{TIMESTEP / units.fs:g} fs, then hit the target',
                 fontsize=12.5)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _atom_colours(x0_nc):
    """A colour per atom from its starting azimuth; the centre atom grey."""
    import matplotlib
    cmap = matplotlib.colormaps['hsv']
    centre_c = x0_nc.mean(axis=0)
    d_nc = x0_nc - centre_c
    azimuth_n = np.arctan2(d_nc[:, 1], d_nc[:, 0])
    colours = [cmap((a / (2 * math.pi)) % 1.0) for a in azimuth_n]
    r_n = np.hypot(d_nc[:, 0], d_nc[:, 1])
    for i in np.flatnonzero(r_n < 0.5):
        colours[i] = (0.6, 0.6, 0.6, 1.0)
    return colours


def _rotation(axis_c, angle):
    """Rotation matrix ``[3, 3]`` by ``angle`` (radians) about ``axis_c``."""
    k_c = np.asarray(axis_c, dtype=float)
    k_c = k_c / np.linalg.norm(k_c)
    k_cc = np.array([[0.0, -k_c[2], k_c[1]], [k_c[2], 0.0, -k_c[0]],
                     [-k_c[1], k_c[0], 0.0]])
    return (np.eye(3) + math.sin(angle) * k_cc
            + (1 - math.cos(angle)) * k_cc @ k_cc)


def _report(r):
    print(f'Ar13 steered to a {TURN_DEGREES:g}° turn plus a '
          f'{SHIFT_C[0]:g} Å shift in {r["steps"]} steps of '
          f'{TIMESTEP / units.fs:g} fs')
    print(f'  loss (mean squared distance to the target): '
          f'{r["loss_initial"]:.3g} -> {r["loss_final"]:.3g} Å²  '
          f'(RMS miss {r["rms_miss_initial"]:.3g} -> '
          f'{r["rms_miss_final"]:.2g} Å)')
    print(f'  L-BFGS-B: {r["iterations"]} iterations, {r["evaluations"]} '
          f'forward runs + backpropagates')
    print(f'  initial kinetic energy of the answer: '
          f'{r["kinetic_energy_optimised"]:.3f} eV')
    verdict = 'yes, bit for bit' if r['exact_return'] else 'NO'
    print(f'  back at the start after the last backpropagate: {verdict} '
          f'({r["exact_returns"]}/{r["evaluations"]} evaluations exact)')
    print(f'  picture: {r["picture"]}')
    print(f'  wall time {r["seconds"]:.1f} s')


if __name__ == '__main__':
    parser = argparse.ArgumentParser(
        description='Steer an argon cluster to a target by optimising its '
                    'initial momenta through ReversibleVerlet.backpropagate.')
    parser.add_argument('--out', default='.', metavar='DIR',
                        help='directory for steer_argon.png (default .)')
    parser.add_argument('--quick', action='store_true',
                        help=f'a cheaper run: {QUICK_ITERATIONS} iterations '
                        f'instead of {ITERATIONS}')
    parser.add_argument('--kinetic-weight', type=float, default=0.0,
                        metavar='W', help='Å²/eV, weight of the initial '
                        'kinetic energy in the loss (default 0)')
    args = parser.parse_args()
    _report(main(args.out, args.quick, args.kinetic_weight))
