"""A chaotic pendulum chain run forward and back: exactly, and not.

The paper's web demo (J. Stam, "An Exact Bitwise Reversible Integrator"):
a chain of beads on stiff springs, pinned at one end, falls from
horizontal under gravity and thrashes about chaotically.  After ``steps``
steps the time step is negated and the chain is run back as many steps.

* :class:`~ase_reversible.ReversibleVerlet` retraces its own path and
  lands on its start bit for bit (positions and momenta compared with
  ``np.array_equal``), at every recorded step of the way back, not only at
  the end.
* :class:`ase.md.verlet.VelocityVerlet`, run on an identical copy (the
  same start, taken after ``ReversibleVerlet``'s constructor snapped it to
  its grid), does not: a float step taken with ``-dt`` does not undo the
  rounding of the step it retraces.  That error is ~1e-16 relative, chaos amplifies it about tenfold
  every 20 fs, and by the end of the return the copy is somewhere else
  entirely: with the settings below it misses its start by several Å.

Both are velocity Verlet with the same time step; going forward they
differ only in rounding (float64 against the automatic quanta, 2**-39 Å and
2**-46 amu Å per time unit), and that they part ways there too is the
same chaos acting on their different roundings.  The point is the
return: each is compared with its own way out.

Run it::

    python examples/chaotic_chain.py --out docs/images    # 7-10 s
    python examples/chaotic_chain.py --out /tmp --quick    # 4-7 s

It writes ``chaotic_chain.png`` (snapshots and the size of each
integrator's departure from its own forward path during the return) and
``chaotic_chain.gif`` (the animation), and prints a short report;
:func:`main` returns the numbers.  Needs matplotlib and pillow besides the
package.

Units are ASE's: Å, amu, eV, and the ASE time unit (Å sqrt(amu/eV), about
10.18 fs); the pictures give times in fs.  The beads weigh 1 amu and the
links are 1 Å, so gravity in eV/(Å amu) is the acceleration in Å per time
unit squared.
"""

from __future__ import annotations

import argparse
import io
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ase import units
from ase.md.verlet import VelocityVerlet

from ase_reversible import ReversibleVerlet
from ase_reversible.calculators import PendulumChain, make_chain
from ase_reversible import INFO_KEY

RV_COLOUR = 'tab:blue'
VV_COLOUR = 'tab:red'
GHOST_COLOUR = '0.72'


@dataclass(frozen=True)
class Setup:
    """The run.  Lengths Å, masses amu, times ASE units."""

    n_links: int = 10
    link_length: float = 1.0
    mass: float = 1.0
    #: Degrees from straight down: released from horizontal, at rest.
    start_angle: float = 90.0
    #: eV/Å², as in :class:`~ase_reversible.calculators.PendulumChain`'s default.
    stiffness: float = 1000.0
    #: eV/(Å amu).
    gravity: float = 1.0
    #: Half the step the chain's docstring says resolves its fastest mode
    #: (0.0125), to keep Verlet's O(dt²) energy error small when the free
    #: end whips round: within 0.5% of the energy the chain releases as it
    #: falls over the whole run (0.23 eV of 55 eV).
    timestep: float = 0.00625
    #: Each way: T = 50 time units (509 fs).  VelocityVerlet's miss grows
    #: about tenfold per 2 time units of T (1.4e-7, 2.2e-4, 0.036 and 1.1
    #: Å for T = 25, 30, 35 and 40); at T = 50 it is several Å.
    steps: int = 8000
    #: Steps between recorded states (for the pictures and the check that
    #: the way back passes through the forward states).
    record_every: int = 10
    #: Animation frames, both directions together.
    gif_frames: int = 100
    #: The energy check's tolerance as a fraction of ``m g L n (n+1)/2``,
    #: the potential energy released between horizontal and hanging
    #: straight down.  The default tolerance (kinetic energy at the anchor,
    #: at least that of 100 K) is an atomistic scale; this chain starts at
    #: rest and falls through tens of eV.
    energy_tolerance_fraction: float = 0.01

    @property
    def fall_energy(self):
        """``m g L n (n+1) / 2``, eV."""
        n = self.n_links
        return self.mass * self.gravity * self.link_length * n * (n + 1) / 2


#: The smoke-test version: the same chain for T = 40 (407 fs), fewer frames.
QUICK = Setup(steps=6400, gif_frames=24)


@dataclass
class RoundTrip:
    """Recorded states of one integrator's forward and backward run.

    ``forward_x`` and ``back_x`` are ``[n_records, n_atoms, 3]`` (Å),
    ``forward_p`` and ``back_p`` the momenta (amu Å / ASE time unit), and
    ``energy`` ``[2 * n_records - 1]`` the total energy (eV) in the order
    the states were visited.  Record ``k`` is at time ``times[k]`` (ASE
    units) on both runs: the way back is stored in the forward order, so
    that ``back_x[k]`` and ``forward_x[k]`` are the same moment.
    """

    times: np.ndarray
    forward_x: np.ndarray
    forward_p: np.ndarray
    back_x: np.ndarray
    back_p: np.ndarray
    energy: np.ndarray

    def departure(self):
        """``[n_records]``: max |back - forward| position component, Å."""
        return np.abs(self.back_x - self.forward_x).max(axis=(1, 2))

    def retraced(self):
        """``[n_records]``: True where the way back is bitwise the way out."""
        return np.array([np.array_equal(bx, fx) and np.array_equal(bp, fp)
                         for bx, fx, bp, fp in zip(self.back_x, self.forward_x,
                                                   self.back_p,
                                                   self.forward_p)])


def build(setup: Setup):
    """The chain at its start with a ``PendulumChain`` calculator."""
    s = setup
    atoms = make_chain(s.n_links, s.link_length, s.mass, s.start_angle)
    atoms.calc = PendulumChain(stiffness=s.stiffness,
                               rest_length=s.link_length, gravity=s.gravity)
    return atoms


def round_trip(dyn, steps, every, turn_around):
    """``dyn.run(steps)``, ``turn_around()``, ``dyn.run(steps)``, recorded.

    Records every ``every`` steps (``steps`` must be a multiple) through an
    observer, so the runs themselves are the plain ``run`` calls.
    """
    atoms = dyn.atoms
    states = []

    def record():
        states.append((atoms.get_positions(), atoms.get_momenta(),
                       atoms.get_total_energy()))

    dyn.attach(record, interval=every)
    dyn.run(steps)
    turn_around()
    dyn.run(steps)
    dyn.observers.remove((record, every, (), {}))
    n = steps // every + 1
    # ASE calls observers at step 0 only before the first run, so the way
    # back has n - 1 records; its missing last one is the turning point.
    x, p, e = (np.array(v) for v in zip(*states))
    return RoundTrip(times=np.arange(n) * every * abs(dyn.dt),
                     forward_x=x[:n], forward_p=p[:n],
                     back_x=x[n - 1:][::-1], back_p=p[n - 1:][::-1],
                     energy=e)


def run(setup: Setup):
    """Both round trips from one start.

    Returns ``(reversible, velocity_verlet, exact)``: two
    :class:`RoundTrip` records and whether ``ReversibleVerlet`` ended
    bitwise on its start.
    """
    s = setup
    if s.steps % s.record_every:
        raise ValueError(f'steps ({s.steps}) must be a multiple of '
                         f'record_every ({s.record_every})')
    atoms = build(s)
    dyn = ReversibleVerlet(atoms, s.timestep, energy_tolerance=(
        s.energy_tolerance_fraction * s.fall_energy))
    # The constructor snapped the start to the grid and wrote it back:
    # this is the state reversal returns to, and the copy's start.
    x0_nc, p0_nc = atoms.get_positions(), atoms.get_momenta()
    twin = atoms.copy()
    twin.info.pop(INFO_KEY, None)
    twin.calc = PendulumChain(**atoms.calc.parameters)
    vv = VelocityVerlet(twin, s.timestep)

    def negate_vv_step():
        vv.dt = -vv.dt

    rv_trip = round_trip(dyn, s.steps, s.record_every, dyn.reverse)
    vv_trip = round_trip(vv, s.steps, s.record_every, negate_vv_step)
    exact = (np.array_equal(atoms.positions, x0_nc)
             and np.array_equal(atoms.get_momenta(), p0_nc))
    return rv_trip, vv_trip, exact


# -- pictures -------------------------------------------------------------

def _box(trips, margin=0.6):
    """``(lo, hi)``: x-z bounds (Å) of every recorded pose, plus a margin."""
    xz = np.concatenate([np.concatenate([t.forward_x, t.back_x])
                         .reshape(-1, 3)[:, [0, 2]] for t in trips])
    return xz.min(axis=0) - margin, xz.max(axis=0) + margin


def _chain_axes(ax, lo, hi):
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect('equal')
    ax.set_xticks([])
    ax.set_yticks([])


def _departure_label(trip, k):
    if np.array_equal(trip.back_x[k], trip.forward_x[k]) and \
            np.array_equal(trip.back_p[k], trip.forward_p[k]):
        return 'on its forward path\nbit for bit'
    return f'off its forward path\nby {trip.departure()[k]:.2g} Å'


def _legend_handles():
    from matplotlib.lines import Line2D
    return [Line2D([], [], marker='o', ms=3, lw=1.3, color=RV_COLOUR,
                   label='ReversibleVerlet'),
            Line2D([], [], marker='o', ms=3, lw=1.3, color=VV_COLOUR,
                   label='VelocityVerlet (same start)'),
            Line2D([], [], marker='o', ms=5, lw=2.5, color=GHOST_COLOUR,
                   label='on the way back: where the same integrator was '
                   'at this time on the way out'),
            Line2D([], [], marker='s', ms=5, lw=0, color='k', label='pin')]


def _moments(vv_trip, stray=0.3):
    """Snapshot columns: ``(kind, record index)``, in the order of the run.

    Forward at 0, T/2 and T; back at 3T/4 (VelocityVerlet still on its
    path to the eye), where its departure first exceeds ``stray`` Å, half
    way from there to the end, and at the end.
    """
    departure = vv_trip.departure()
    n = len(departure) - 1
    beyond = np.flatnonzero(departure > stray)
    first = int(beyond.max()) if len(beyond) else n // 4
    first = min(first, (3 * n) // 4 - 1)
    return [('forward', 0), ('forward', n // 2), ('turn', n),
            ('back', (3 * n) // 4), ('back', first), ('back', first // 2),
            ('back', 0)]


def draw_png(path, setup, rv_trip, vv_trip, exact):
    """Snapshots (rows: integrators; columns: moments) and departures."""
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    times_fs = rv_trip.times / units.fs
    moments = _moments(vv_trip)
    lo, hi = _box([rv_trip, vv_trip])
    cols = len(moments)
    panel_w = 2.0
    panel_h = panel_w * (hi[1] - lo[1]) / (hi[0] - lo[0])
    fig = Figure(figsize=(panel_w * cols + 0.6, 2 * panel_h + 3.9),
                 layout='constrained')
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(3, cols, height_ratios=(panel_h, panel_h, 2.2))
    rows = (('ReversibleVerlet', rv_trip, RV_COLOUR),
            ('VelocityVerlet', vv_trip, VV_COLOUR))
    for r, (name, trip, colour) in enumerate(rows):
        for c, (kind, k) in enumerate(moments):
            ax = fig.add_subplot(grid[r, c])
            _chain_axes(ax, lo, hi)
            if kind == 'back':
                ghost = trip.forward_x[k]
                ax.plot(ghost[:, 0], ghost[:, 2], 'o-', color=GHOST_COLOUR,
                        ms=5, lw=2.5, zorder=1)
                pose = trip.back_x[k]
            else:
                pose = trip.forward_x[k]
            ax.plot(pose[:, 0], pose[:, 2], 'o-', color=colour, ms=3, lw=1.3,
                    zorder=2)
            ax.plot([0], [0], 's', color='k', ms=5, zorder=3)
            if r == 0:
                word = {'forward': 'forward →', 'turn': 'dt → -dt ⇄',
                        'back': '← back'}[kind]
                ax.set_title(f'{word}\nt = {times_fs[k]:.0f} fs',
                             fontsize=9)
            if c == 0:
                ax.text(0.03, 0.05, name, transform=ax.transAxes,
                        fontsize=9, color=colour, fontweight='bold')
            if kind == 'back':
                ax.text(0.03, 0.03, _departure_label(trip, k),
                        transform=ax.transAxes, fontsize=6.5, color=colour,
                        va='bottom')
    fig.legend(handles=_legend_handles(), loc='outside lower center',
               ncols=4, fontsize=9, frameon=False)
    ax = fig.add_subplot(grid[2, :])
    departure = vv_trip.departure()
    shown = departure > 0
    ax.semilogy(times_fs[shown], departure[shown], color=VV_COLOUR,
                label='VelocityVerlet')
    retraced = rv_trip.retraced()
    ax.text(0.99, 0.93, f'ReversibleVerlet: 0 at all {retraced.sum()} of '
            f'{len(retraced)} recorded times (positions and momenta '
            'bitwise equal)' + ('' if retraced.all() else ' -- NOT all!'),
            transform=ax.transAxes, ha='right', va='top', color=RV_COLOUR,
            fontsize=9)
    ax.set_xlim(times_fs[0], times_fs[-1])
    ax.set_xlabel('t (fs)   --   the way back runs from right to left')
    ax.set_ylabel('max |x_back(t) - x_out(t)|\n(Å)', fontsize=9)
    ax.grid(True, which='major', alpha=0.3)
    ax.legend(loc='lower left', fontsize=9)
    ax.set_title('How far each integrator is, on the way back, from where '
                 'it was at the same time on the way out', fontsize=10)
    fig.suptitle(
        f'A {setup.n_links}-link pendulum chain falls from horizontal: '
        f'{setup.steps} steps of {setup.timestep / units.fs:.3f} fs '
        'forward, then the time step is negated and the same number back.'
        f'\nReversibleVerlet returns to its start bit for bit'
        f' ({"verified" if exact else "FAILED"}); VelocityVerlet from the '
        f'same start misses by {departure[0]:.2g} Å.\nGoing forward the '
        'two part ways too (chaos amplifies their different roundings), so '
        'each is compared with its own way out.', fontsize=10.5)
    fig.savefig(path, dpi=110)


def draw_gif(path, setup, rv_trip, vv_trip, frames, width_px=480):
    """The two chains side by side, forward and back; pillow writes it."""
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    n = len(rv_trip.times) - 1
    half = max(frames // 2, 2)
    # (direction, record index): forward 0 -> n, then back n -> 0.
    out = np.linspace(0, n, half).round().astype(int)
    plan = [('forward', k) for k in out] + \
        [('back', k) for k in out[::-1][1:]]
    lo, hi = _box([rv_trip, vv_trip])
    # Layout in inches: header, panel titles, the two panels, legend.
    dpi = 100
    width = width_px / dpi
    side, gap, header, titles, legend = 0.05, 0.08, 0.3, 0.25, 0.3
    panel_w = (width - 2 * side - gap) / 2
    panel_h = panel_w * (hi[1] - lo[1]) / (hi[0] - lo[0])
    height = header + titles + panel_h + legend
    fig = Figure(figsize=(width, height), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    artists = []
    for i, (name, trip, colour) in enumerate(
            (('ReversibleVerlet', rv_trip, RV_COLOUR),
             ('VelocityVerlet', vv_trip, VV_COLOUR))):
        ax = fig.add_axes(((side + i * (panel_w + gap)) / width,
                           legend / height, panel_w / width,
                           panel_h / height))
        _chain_axes(ax, lo, hi)
        ax.set_title(name, color=colour, fontsize=10, fontweight='bold',
                     pad=3)
        ghost, = ax.plot([], [], 'o-', color=GHOST_COLOUR, ms=4, lw=2.5,
                         zorder=1)
        chain, = ax.plot([], [], 'o-', color=colour, ms=3, lw=1.3, zorder=2)
        ax.plot([0], [0], 's', color='k', ms=5, zorder=3)
        note = ax.text(0.03, 0.03, '', transform=ax.transAxes, fontsize=7.5,
                       color=colour, va='bottom')
        artists.append((trip, ghost, chain, note))
    fig.legend(handles=_legend_handles()[2:3], loc='lower center',
               bbox_to_anchor=(0.5, 0.0), fontsize=7, frameon=False)
    title = fig.text(0.5, 1 - 0.06 / height, '', ha='center', va='top',
                     fontsize=10.5, family='monospace')
    times_fs = rv_trip.times / units.fs
    images = []
    for kind, k in plan:
        for trip, ghost, chain, note in artists:
            pose = trip.forward_x[k] if kind == 'forward' else trip.back_x[k]
            chain.set_data(pose[:, 0], pose[:, 2])
            if kind == 'back':
                ghost.set_data(trip.forward_x[k][:, 0],
                               trip.forward_x[k][:, 2])
                note.set_text(_departure_label(trip, k))
            else:
                ghost.set_data([], [])
                note.set_text('')
        arrow = 'forward →' if kind == 'forward' else '← back   '
        title.set_text(f'{arrow}  t = {times_fs[k]:4.0f} fs')
        canvas.draw()
        rgba = np.asarray(canvas.buffer_rgba())
        images.append(Image.fromarray(rgba[..., :3].copy()))
    # One palette for all frames keeps colours steady and the file small;
    # a frame from the way back has every colour in it.
    palette = images[-1].quantize(colors=48,
                                  method=Image.Quantize.MEDIANCUT)
    frames_p = [im.quantize(palette=palette, dither=Image.Dither.NONE)
                for im in images]
    durations = [70] * len(frames_p)
    durations[0] = 1200                 # the start, at rest
    durations[half - 1] = 800           # the turning point
    durations[-1] = 3000                # the return: on the start, or not
    buffer = io.BytesIO()
    frames_p[0].save(buffer, format='GIF', save_all=True,
                     append_images=frames_p[1:], duration=durations, loop=0,
                     optimize=True, disposal=1)
    Path(path).write_bytes(buffer.getvalue())


def main(out_dir='.', quick=False) -> dict:
    """Run both integrators forward and back, draw, and report.

    Returns a dict with ``pictures`` (paths of the PNG and the GIF),
    ``exact_return`` (True if ReversibleVerlet ended bitwise on its start,
    positions and momenta), ``velocity_verlet_miss`` (Å, the largest
    position component error of the VelocityVerlet copy after its round
    trip), ``steps`` (each way), ``timestep`` (ASE time units),
    ``max_energy_drift`` (eV, ReversibleVerlet's largest |E - E0| over the
    recorded states; ``energy_tolerance`` is the check's tolerance) and
    ``seconds``.
    """
    started = time.perf_counter()
    setup = QUICK if quick else Setup()
    rv_trip, vv_trip, exact = run(setup)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / 'chaotic_chain.png'
    gif = out_dir / 'chaotic_chain.gif'
    draw_png(png, setup, rv_trip, vv_trip, exact)
    draw_gif(gif, setup, rv_trip, vv_trip, setup.gif_frames)
    return {'pictures': [str(png), str(gif)],
            'exact_return': bool(exact),
            'velocity_verlet_miss': float(vv_trip.departure()[0]),
            'steps': setup.steps,
            'timestep': setup.timestep,
            'max_energy_drift': float(np.abs(rv_trip.energy
                                             - rv_trip.energy[0]).max()),
            'energy_tolerance': setup.energy_tolerance_fraction
            * setup.fall_energy,
            'retraced_everywhere': bool(rv_trip.retraced().all()),
            'seconds': time.perf_counter() - started}


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='.',
                        help='directory for the pictures')
    parser.add_argument('--quick', action='store_true',
                        help='T = 40 instead of 50 time units, fewer frames '
                        '(for smoke tests)')
    args = parser.parse_args()
    report = main(args.out, args.quick)
    t = report['steps'] * report['timestep']
    print(f"{report['steps']} steps of {report['timestep'] / units.fs:.4f} "
          f"fs each way (T = {t / units.fs:.0f} fs), "
          f"{report['seconds']:.1f} s")
    print('ReversibleVerlet back at the start bit for bit:',
          report['exact_return'],
          '(and on its forward path at every recorded step:',
          f"{report['retraced_everywhere']})")
    print(f"VelocityVerlet copy misses its start by "
          f"{report['velocity_verlet_miss']:.3g} Å (largest component)")
    print(f"ReversibleVerlet energy drift at most "
          f"{report['max_energy_drift']:.3g} eV "
          f"(check tolerance {report['energy_tolerance']:.3g} eV)")
    print('pictures:', ', '.join(report['pictures']))
