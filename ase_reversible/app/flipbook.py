"""Browse a simulation back and forth without storing its frames.

A :class:`Flipbook` holds a reversible dynamics
(:class:`~ase_reversible.ReversibleVerlet`, a thermostat:
:class:`~ase_reversible.ReversibleNose`,
:class:`~ase_reversible.ReversibleLangevin`,
:class:`~ase_reversible.ReversibleBussi`, or a barostat:
:class:`~ase_reversible.ReversibleIsotropicNPT`,
:class:`~ase_reversible.ReversibleNPT`) and a frame number.  Asking
for another frame runs the dynamics to it: forward if it is later,
backward (time step negated, exactly retracing the path) if it is
earlier.  Because every step is undone bit for bit, frame ``k``
is the same state however it was reached, so nothing is stored: memory
is one state whatever the length of the run, and a frame costs the steps
between it and the current one.

Three ways to look:

- :meth:`Flipbook.show`: a matplotlib window; the arrow keys step (right /
  left one frame, up / down ten), Home goes back to frame 0.
- :meth:`Flipbook.render`: any frame to a PNG.
- :meth:`Flipbook.save_gif`: any sequence of frames (forward, backward or
  both) to an animated GIF.

``python -m ase_reversible flipbook`` opens one on a built-in scene or on
a trajectory frame, replayed with the dynamics that wrote the file
(:mod:`ase_reversible.md.replay`; ``--help`` lists the options).

matplotlib is imported only when something is drawn, and with no display
the Agg backend renders off screen.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import ReversibilityError
from ..md import ReversibleDynamics
from .view import AtomsView

#: Key -> frames to move.  'home' is handled apart.
KEY_STEPS = {'right': 1, 'left': -1, 'up': 10, 'down': -10,
             'pageup': 100, 'pagedown': -100}


class Flipbook:
    """A simulation to page through: frames are recomputed, not stored.

    Frame ``k`` is the state ``k * stride`` steps after the state the
    dynamics had when the flipbook was made (frame 0).

    Parameters
    ----------
    dyn : ReversibleDynamics
        The dynamics, at the state that becomes frame 0.  A dynamics
        with information buffers (ReversibleLangevin, ReversibleBussi,
        the barostats) cannot go before its anchor (it raises
        :class:`~ase_reversible.RetraceLimitError` there), so frame 0 is
        as far back as it goes if it is at its anchor.  Its observers
        (trajectory writers, loggers) are not called while the flipbook
        steps: browsing does not write frames.
    stride : int
        Steps per frame (>= 1).
    view : callable, optional
        ``view(ax, atoms)`` draws the atoms on a cleared axes; default
        :class:`AtomsView` in the x-y plane.
    limits : ((float, float), (float, float)), optional
        Axis limits, Å.  Default: the extent of frame 0 in the view's
        plane, with a margin of a quarter of its size.
    figsize : (float, float)
        Inches.
    first, last : int or None
        Frames the flipbook may visit (``first <= k <= last``); None is
        no bound.  Default ``first=0``: not before the starting state.
    """

    def __init__(self, dyn, stride=1, view=None, limits=None,
                 figsize=(5.0, 5.0), first=0, last=None):
        if not isinstance(dyn, ReversibleDynamics):
            raise TypeError(
                f'Flipbook needs a reversible dynamics (ReversibleVerlet, '
                f'ReversibleNose, ReversibleLangevin, ReversibleBussi, '
                f'ReversibleIsotropicNPT, ReversibleNPT), got '
                f'{type(dyn).__name__}: other dynamics cannot step back to '
                'an earlier frame without storing it.')
        if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) \
                or stride < 1:
            raise ValueError(f'stride must be a whole number of steps >= 1, '
                             f'got {stride!r}')
        self.dyn = dyn
        self.stride = int(stride)
        self.view = AtomsView() if view is None else view
        self.first, self.last = first, last
        self.figsize = figsize
        #: Step count of the dynamics at frame 0.
        self._origin = dyn.step_index
        #: Simulated time at frame 0, ASE time units: the dynamics' clock,
        #: which a run resumed from a trajectory frame continues from the
        #: frame's restart record, not 0.
        self.time0 = dyn.get_time()
        self.limits = self._default_limits() if limits is None else limits
        self._figure = None
        self._message = ''
        self._heading = ''

    # -- where we are ----------------------------------------------------

    @property
    def atoms(self):
        """The atoms of the dynamics, at the current frame."""
        return self.dyn.atoms

    @property
    def steps(self) -> int:
        """Steps from frame 0 to the current state (may be between frames
        after a failed move)."""
        return self.dyn.step_index - self._origin

    @property
    def frame(self) -> float:
        """The current frame; not a whole number only after a move that
        failed part way."""
        steps = self.steps
        return steps // self.stride if steps % self.stride == 0 \
            else steps / self.stride

    @property
    def time(self) -> float:
        """Simulated time of the current state, ASE time units: the
        dynamics' ``get_time()``, continued from the restart record of a
        frame the run resumed (:attr:`time0` at frame 0; real time, for
        ReversibleNose not a multiple of the time step)."""
        return self.dyn.get_time()

    # -- moving ----------------------------------------------------------

    def goto(self, frame):
        """Run the dynamics to ``frame``, forward or backward; return self.

        On an error on the way (the calculator fails, the energy check
        trips, an atom leaves the grid's range) the error propagates and
        the dynamics stay at the last completed step: a valid state, still
        exactly reversible, reported by :attr:`steps` and :attr:`frame`.
        """
        frame = self._check_frame(frame)
        delta = frame * self.stride - self.steps
        if delta:
            self._run(delta)
        return self

    def forward(self, frames=1):
        """Move ``frames`` frames later (earlier if negative)."""
        return self.goto(self._nearest_frame() + frames)

    def back(self, frames=1):
        """Move ``frames`` frames earlier."""
        return self.goto(self._nearest_frame() - frames)

    def _nearest_frame(self):
        return int(math.floor(self.frame))

    def _check_frame(self, frame):
        if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)):
            raise TypeError(f'frame must be a whole number, got {frame!r}')
        frame = int(frame)
        if (self.first is not None and frame < self.first) or \
                (self.last is not None and frame > self.last):
            raise ValueError(f'frame {frame} is outside this flipbook '
                             f'(frames {self.first} to '
                             f'{"unbounded" if self.last is None else self.last}'
                             '); pass first=/last= to widen it.')
        return frame

    def _run(self, steps):
        dyn = self.dyn
        forward = (steps > 0) == (dyn.dt > 0)
        self._heading = 'forward' if steps > 0 else 'backward'
        observers, dyn.observers = dyn.observers, []
        try:
            if not forward:
                dyn.reverse()
            try:
                dyn.run(abs(steps))
            finally:
                if not forward:
                    dyn.reverse()
        finally:
            dyn.observers = observers

    # -- drawing ---------------------------------------------------------

    def draw(self, ax=None, title=True):
        """Draw the current frame on ``ax`` (default: the flipbook's own
        figure, made on first use) and return the axes."""
        if ax is None:
            ax = self._own_axes()
        ax.cla()
        self.view(ax, self.atoms)
        (x0, x1), (y0, y1) = self.limits
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect('equal')
        if title:
            ax.set_title(self.caption(), fontsize=10)
        return ax

    def caption(self):
        """``frame k  step s  t = ... fs  (forward)``: where the flipbook
        is (frame and step from frame 0, the simulated time), which way it
        last moved, and the last error if any."""
        frame = self.frame
        frame = f'{frame:d}' if isinstance(frame, int) else f'{frame:.3g}'
        from ase import units
        text = (f'frame {frame}   step {self.steps}   '
                f't = {self.time / units.fs:.6g} fs')
        if self._heading:
            text += f'   ({self._heading})'
        return f'{text}\n{self._message}' if self._message else text

    def render(self, frame, path, title=True):
        """Go to ``frame`` and save its picture as a PNG at ``path``.

        ``title``: show :meth:`caption` above the picture.  Returns the
        path (:class:`pathlib.Path`).
        """
        self.goto(frame)
        self.draw(title=title)
        path = Path(path)
        self._figure.savefig(path, dpi=100)
        return path

    def save_gif(self, path, frames, fps=20):
        """Animate ``frames`` (an iterable of frame numbers, in the order
        shown, e.g. ``[*range(0, 100), *range(100, -1, -1)]``) into an
        animated GIF at ``path``; ``fps`` frames per second.  The
        dynamics are left at the last frame.  Returns the path."""
        images = []
        self._heading = ''  # the first frame was not reached by this film
        for frame in frames:
            self.goto(frame)
            self.draw()
            images.append(self._snapshot())
        if not images:
            raise ValueError('frames is empty: give at least one frame.')
        path = Path(path)
        images[0].save(path, save_all=True, append_images=images[1:],
                       duration=max(1, round(1000 / fps)), loop=0,
                       optimize=False)
        return path

    def _snapshot(self):
        from PIL import Image
        canvas = self._figure.canvas
        canvas.draw()
        rgba = np.asarray(canvas.buffer_rgba())
        return Image.fromarray(rgba[:, :, :3]).convert(
            'P', palette=Image.Palette.ADAPTIVE, colors=64)

    def _own_axes(self):
        if self._figure is None:
            from matplotlib.figure import Figure
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            self._figure = Figure(figsize=self.figsize)
            FigureCanvasAgg(self._figure)
            self._figure.add_subplot()
            self._figure.subplots_adjust(left=0.16, bottom=0.12, right=0.96,
                                         top=0.88)
        return self._figure.axes[0]

    # -- interactive -----------------------------------------------------

    def on_key(self, event):
        """Handle a matplotlib key press: arrows step, Home rewinds.

        Errors from the dynamics are shown in the title, not raised: the
        state stays valid and the keys keep working.
        """
        if event.key == 'home':
            target = 0 if self.first is None else max(0, self.first)
        elif event.key in KEY_STEPS:
            target = self._nearest_frame() + KEY_STEPS[event.key]
            if self.first is not None:
                target = max(target, self.first)
            if self.last is not None:
                target = min(target, self.last)
        else:
            return
        self._message = ''
        try:
            self.goto(target)
        except (ReversibilityError, ArithmeticError, RuntimeError) as error:
            self._message = f'stopped: {type(error).__name__}'
        self.draw(ax=event.canvas.figure.axes[0])
        event.canvas.draw_idle()

    def connect(self, figure):
        """Draw on ``figure`` and route its key presses to :meth:`on_key`;
        returns the connection id."""
        if not figure.axes:
            figure.add_subplot()
        self._figure = figure
        self.draw()
        return figure.canvas.mpl_connect('key_press_event', self.on_key)

    def show(self):
        """Open a window and browse with the keys (blocks until closed)."""
        import matplotlib.pyplot as plt
        figure = plt.figure(figsize=self.figsize)
        self.connect(figure)
        figure.suptitle('← → one frame, ↑ ↓ ten, Home: frame 0',
                        fontsize=8)
        plt.show()

    def _default_limits(self):
        a, b = self.view.axes() if hasattr(self.view, 'axes') else (0, 1)
        x_nc = self.atoms.positions
        limits = []
        for axis in (a, b):
            lo, hi = float(x_nc[:, axis].min()), float(x_nc[:, axis].max())
            centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            half = 1.25 * half + 1.0
            limits.append((centre - half, centre + half))
        # Equal aspect: give both axes the larger span.
        half = max(hi - lo for lo, hi in limits) / 2
        return tuple((0.5 * (lo + hi) - half, 0.5 * (lo + hi) + half)
                     for lo, hi in limits)
