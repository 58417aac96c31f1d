"""Losses along a run: where the retrace adds gradients, and how far back
each one is carried.

A loss on many states of a run -- a time average of a radial distribution
function, the correlation of velocities at several lags -- depends
directly on each state it samples.  One retrace gathers all of it: at each
sampled state the user's ``loss(atoms, k)`` gives that state's direct
``dL/dx``, ``dL/dp``, which are added to the cotangents as the retrace
passes.

A *window* truncates the gradient: each sampled state's gradient is carried
back at most ``window`` steps, then dropped (what came before is treated
as given).  Gradients through a chaotic run grow exponentially with its
length (docs/adjoint.md measures the growth for argon); the truncated
objective is what trainers of force fields through simulations use.
Windows do not overlap (``window <= every``), so one set of cotangents
serves them all; steps outside every window are undone with no adjoint
work at all.
"""

from __future__ import annotations

from .cotangents import checked_gradient


class LossSchedule:
    """Decides, at each state a retrace meets, what to add and whether to
    carry the adjoint through the next step back.

    Parameters
    ----------
    steps : int
        Steps retraced; states are numbered ``k = steps, ..., 0`` (steps
        from the state the retrace ends on).
    loss : callable or None
        ``loss(atoms, k) -> None or (dL/dx, dL/dp)`` at the sampled states
        ``k % every == 0`` (either part may be None).
    every : int
        Sampling interval, steps (>= 1).
    window : int or None
        Steps each sampled state's gradient is carried back; None: all
        the way.
    show : callable
        Makes the atoms show the present state's momenta (positions are
        always shown).
    increments : callable
        ``increments(dL/dx, dL/dp) -> {variable: cotangent}`` at the
        present state (the dynamics' change of variables).
    atoms : ase.Atoms
    """

    def __init__(self, steps, loss, every, window, show, increments, atoms):
        self.steps, self.loss, self.every = steps, loss, every
        self.window = window
        self.show, self.increments, self.atoms = show, increments, atoms
        self.cotangents = None
        #: Where the open window ends (None: no window open; 0 or below:
        #: it reaches the first state, whose cotangents are returned).
        self._end = None

    def start(self, cotangents, given):
        """Begin at state ``steps`` with the cotangents holding the
        gradients ``given`` there (whether any is nonzero)."""
        self.cotangents = cotangents
        if given:
            self._open(self.steps)

    def _open(self, k):
        self._end = -1 if self.window is None else k - self.window

    def __call__(self, k):
        """At state ``k``: returns whether the step back to ``k - 1``
        carries the adjoint."""
        cotangents = self.cotangents
        if self._end is not None and k == self._end and k > 0:
            cotangents.clear()
            self._end = None
        if self.loss is not None and k % self.every == 0:
            self._add(k)
        return self._end is not None and k > self._end

    def _add(self, k):
        self.show()
        given = self.loss(self.atoms, k)
        if given is None:
            return
        try:
            dx, dp = given
        except (TypeError, ValueError):
            raise TypeError(
                f'loss(atoms, k) must return None or a pair (dL/dx, dL/dp) '
                f'of arrays [n_atoms, 3] (either may be None); at k={k} it '
                f'returned {type(given).__name__}') from None
        n = len(self.atoms)
        dx = checked_gradient(dx, n, f'dL/dx from loss at k={k}')
        if dp is not None:
            dp = checked_gradient(dp, n, f'dL/dp from loss at k={k}')
            # A kick still pending at this state pulls back the momentum
            # cotangent of the later states only.
            self.cotangents.flush()
        if not (dx.any() or (dp is not None and dp.any())):
            return
        for name, value in self.increments(dx, dp).items():
            self.cotangents[name] += value
        if self._end is None or self.window is not None:
            self._open(k)


def checked_schedule(loss, every, window):
    """``(every, window)``, checked against each other."""
    if loss is not None and not callable(loss):
        raise TypeError('loss must be a callable loss(atoms, k) returning '
                        f'None or (dL/dx, dL/dp), got {type(loss).__name__}')
    every = _count(every, 'every', 1)
    if window is not None:
        window = _count(window, 'window', 1)
        if loss is not None and window > every:
            raise ValueError(
                f'window={window} is longer than every={every}: windows '
                'would overlap, and each would need cotangents of its own. '
                f'Sample less often (every >= {window}) or use a shorter '
                'window.')
    return every, window


def _count(value, name, least):
    try:
        count = int(value)
    except (TypeError, ValueError):
        raise TypeError(f'{name} must be a whole number of steps, got '
                        f'{value!r}') from None
    if count != value or count < least:
        raise ValueError(f'{name} must be a whole number of steps >= '
                         f'{least}, got {value!r}')
    return count
