"""The engine: runs a plan of exact sub-steps forwards and backwards.

It owns what every exact dynamics shares: the plan for the present time
step (composed, merged, its coefficients prepared once per ``dt``), the
checkpoint and rollback of a whole step over every variable and every piece
of side state, the direction of time, the exact clock, the anchor that
reversal leads back to, the retrace that integrates an adjoint, and the
check of a conserved quantity.  It knows nothing of ASE.
"""

from __future__ import annotations

import math


from ..errors import UnstableIntegrationError
from .plans import SubStep, compose

#: How far (as a fraction of the tolerance) the trigger of an
#: :class:`InvariantCheck` may move before the quantity is measured.
TRIGGER_FRACTION = 0.5
#: The trigger is read before every this many steps: a blow-up is caught
#: within two steps at half the cost of reading it before every step.
TRIGGER_EVERY = 2


class Engine:
    """A dynamics declared as exact variables and a palindromic scheme.

    Parameters
    ----------
    variables : dict of str to ExactVariable
        The exact variables, by name.
    scheme : tuple of (SubStep, float)
        The second-order palindrome of sub-steps and time-step fractions.
    composition : Composition
        How the scheme is composed to higher order.
    dt : float
        The time step (any unit the sub-steps agree on); its sign is the
        direction of time.
    side : sequence
        Further state with ``checkpoint()`` and ``rollback()`` (an
        information buffer, say) that a step must restore when it fails.
    invariant : InvariantCheck, optional
        Checked before a step.

    Attributes
    ----------
    plan : tuple of (SubStep, float)
        The composed, merged sub-steps and their fractions of ``dt``.
    step_index : int
        Signed steps taken with the present ``|dt|`` (forward +1, back -1).
    anchor_index : int
        ``step_index`` at the anchor: reversal leads back no further.
    """

    def __init__(self, variables, scheme, composition, dt, side=(),
                 invariant=None):
        self.variables = dict(variables)
        self.composition = composition
        self.plan = compose(scheme, composition)
        self.substeps = tuple(dict.fromkeys(s for s, _ in self.plan))
        self._parts = (*self.variables.values(), *side, *self.substeps)
        # Sub-steps without caches inherit SubStep's checkpoint, which does
        # nothing: not called before every step.
        self._checkpoints = tuple(
            part.checkpoint for part in self._parts
            if getattr(type(part), 'checkpoint', None) is not SubStep.checkpoint)
        self.invariant = invariant
        self.step_index = self.anchor_index = 0
        #: Signed steps taken with each earlier |dt|, so that the clock
        #: returns exactly to where it was when the steps are undone.
        self._steps_by_size = {}
        self._elapsed = []
        self._dt = None
        self.set_dt(dt)
        self.anchor = self.snapshot()

    # -- time -----------------------------------------------------------

    @property
    def dt(self) -> float:
        """The time step; change it with :meth:`set_dt`."""
        return self._dt

    @property
    def direction(self) -> int:
        """+1 forward, -1 backward."""
        return 1 if self._dt > 0 else -1

    def set_dt(self, dt):
        """Use the time step ``dt`` from the next step on.

        A negated ``dt`` retraces exactly.  A new size starts the count of
        steps afresh (the clock stays exact) and returns the number of
        steps taken since the anchor, which then moves here; 0 otherwise.
        """
        old, self._dt = self._dt, dt
        # Negating dt negates every coefficient exactly.
        self._prepared = tuple((s, s.prepare(c * dt)) for s, c in self.plan)
        if old is None or abs(dt) == abs(old):
            return 0
        taken = self.step_index - self.anchor_index
        counts = self._steps_by_size
        counts[abs(old)] = counts.get(abs(old), 0) + self.step_index
        self.step_index = self.anchor_index = counts.pop(abs(dt), 0)
        for h in [h for h, k in counts.items() if k == 0]:
            del counts[h]
        self._elapsed = [k * h for h, k in counts.items()]
        if taken:
            self.anchor = self.snapshot()
        return taken

    def elapsed(self) -> float:
        """Time since the engine started, in the unit of ``dt``; goes back
        when the engine runs backwards."""
        now = self.step_index * abs(self._dt)
        if self._elapsed:
            # One correctly rounded sum over every step size used: the same
            # multiset of steps gives the same time, whatever the order.
            now = math.fsum([*self._elapsed, now])
        return now

    # -- state ----------------------------------------------------------

    def snapshot(self) -> dict:
        """Copies of every variable's counts, by name."""
        return {name: v.ints.copy() for name, v in self.variables.items()}

    def install(self, counts):
        """Set the variables to ``counts`` (dict of int64 arrays by name)
        and make this the anchor of reversal."""
        for name, v in self.variables.items():
            v.reset(counts[name])
        self.anchor = self.snapshot()
        self.anchor_index = self.step_index
        if self.invariant is not None:
            self.invariant.reset()

    @property
    def other_step_sizes(self) -> bool:
        """Whether steps of another ``|dt|`` are still on the clock (taken
        and not undone)."""
        return bool(self._steps_by_size)

    @property
    def steps_since_anchor(self) -> int:
        """Steps that can be retraced in the present direction."""
        return (self.step_index - self.anchor_index) * self.direction

    # -- stepping -------------------------------------------------------

    def step(self, number=None):
        """One step of the plan; if anything fails, all is as before it.

        ``number`` (ASE's count of steps) decides whether the invariant is
        checked first.
        """
        if self.invariant is not None and number is not None:
            self.invariant.check(number)
        for checkpoint in self._checkpoints:
            checkpoint()
        try:
            for substep, argument in self._prepared:
                substep.apply(argument)
        except BaseException:
            self._rollback()
            raise
        self.step_index += self.direction

    def _retrace_step(self, prepared, cotangents):
        """One step back: each sub-step undoes the forward sub-step with
        the opposite coefficient, after pulling the cotangents back
        through it at the values it saw (none if ``cotangents`` is
        None)."""
        for checkpoint in self._checkpoints:
            checkpoint()
        try:
            for substep, argument, forward_ch in prepared:
                if cotangents is not None:
                    substep.adjoint(cotangents, forward_ch)
                substep.apply(argument)
        except BaseException:
            self._rollback()
            raise
        self.step_index += self.direction

    def _rollback(self):
        # Updates never overwrite the checkpoint, so going back to it
        # undoes a partial step exactly.
        for part in self._parts:
            part.rollback()

    def reverse(self):
        """Flip the direction of time."""
        self.set_dt(-self._dt)

    def retrace(self, steps, cotangents, visit=None):
        """Undo ``steps`` steps while pulling ``cotangents`` back.

        ``cotangents`` holds dL/d(variable) by name and ``flush()``; the
        sub-steps' :meth:`~.plans.SubStep.adjoint` update it.  ``visit(k)``,
        if given, is called at each state met, ``k = steps, ..., 0`` (its
        steps from the state the retrace ends on): it may add to the
        cotangents (flushing first what it must not merge with) and
        returns whether the step from state ``k`` back to ``k - 1`` is to
        carry the adjoint; a step that does not is undone with no adjoint
        work at all.  Afterwards the variables are ``steps`` steps back
        and ``dt`` has its sign again, also if a step fails (the state is
        then that of the last completed step).
        """
        self.reverse()
        try:
            retrace = tuple((s, s.prepare(c * self._dt), -(c * self._dt))
                            for s, c in self.plan)
            for k in range(steps, 0, -1):
                carry = True if visit is None else visit(k)
                self._retrace_step(retrace, cotangents if carry else None)
            if visit is not None:
                visit(0)
            cotangents.flush()
        finally:
            self.reverse()
            if self.invariant is not None:
                self.invariant.alarm = False


class InvariantCheck:
    """Stops a run whose conserved quantity drifted beyond a tolerance.

    Attributes ``interval`` and ``tolerance`` are the parameters;
    ``reference`` is the value at the anchor and ``limit`` the tolerance in
    force, both set by the first check after the anchor.

    The conserved quantity can be dear to measure (a potential energy the
    calculator computes in a separate pass), so it is measured on a
    schedule; a blow-up between two scheduled checks is caught by a cheap
    ``trigger`` read before every second step: once it has moved by more
    than ``TRIGGER_FRACTION`` of the tolerance since the last measurement,
    the quantity is measured at once.  An unstable step pumps energy into the
    motion, so the trigger (the kinetic energy) moves in the very step the
    energy goes wrong; a stable run moves it by far less between two
    scheduled checks and pays only for the trigger.

    A slow drift is caught by checking more often as it nears the
    tolerance: a check that leaves a margin ``m < 1/2`` (a fraction of
    the tolerance) asks for the next one ``interval * m**2`` steps later.

    Parameters
    ----------
    interval : int
        Check at steps 1, 2, 4, 8, ... (the powers of two below
        ``interval``) and every ``interval`` steps; 0: never (and no
        trigger either).
    tolerance : float or None
        Largest allowed change since the anchor; None: what ``measure``
        proposes at the anchor.
    measure : callable
        ``measure() -> (value, proposed_tolerance)``.
    explain : callable
        ``explain(number, drift, tolerance) -> str``, the error message.
    trigger : callable, optional
        ``trigger() -> float`` in the unit of the value, cheap.

    Attributes
    ----------
    measurements : int
        Times the quantity was measured; ``triggered`` of them were asked
        for by the trigger.
    """

    def __init__(self, interval, tolerance, measure, explain, trigger=None):
        self.interval = interval
        self.tolerance = tolerance
        self.measure = measure
        self.explain = explain
        self.trigger = trigger
        self.measurements = self.triggered = 0
        self.reset()

    def reset(self):
        """Take the next value checked as the reference."""
        self.reference = self.limit = None
        self._pulled = None  # the trigger's value at the last measurement
        self._next = math.inf  # the next step the drift asks to check
        self.alarm = False

    def arm_for_retrace(self):
        """The way back may start outside the tolerance (a run that ended
        between checks): stay quiet until the value is inside again."""
        self.alarm = True

    def due(self, number) -> bool:
        """Whether step ``number`` is one that is checked."""
        # Checks at the powers of two catch a time step that blows up at
        # once or soon; then one value per interval keeps the cost low, and
        # values come closer together once a drift nears the tolerance.
        interval = self.interval
        return bool(interval) and (
            number % interval == 0 or number >= self._next
            or (number < interval and number & (number - 1) == 0))

    def check(self, number):
        """Raise :class:`~ase_reversible.UnstableIntegrationError` once if
        the value at step ``number`` drifted beyond the tolerance."""
        if not self.interval:
            return
        trigger = self.trigger
        if self.reference is not None and not self.due(number):
            if trigger is None or number % TRIGGER_EVERY:
                return
            pulled = trigger()
            if abs(pulled - self._pulled) <= TRIGGER_FRACTION * self.limit:
                return
            self.triggered += 1
        else:
            pulled = None if trigger is None else trigger()
        self.measurements += 1
        self._pulled = pulled
        value, proposed = self.measure()
        if self.reference is None:
            self.reference = value
            self.limit = (self.tolerance if self.tolerance is not None
                          else proposed)
            return
        drift = value - self.reference
        if abs(drift) <= self.limit:
            self.alarm = False
            # A slow drift crosses the tolerance between two checks: past
            # half the tolerance the gap shrinks with the square of the
            # margin left, down to one step for the last tenth.
            margin = 1.0 - abs(drift) / self.limit if self.limit else 0.0
            self._next = (number + max(1, int(self.interval * margin**2))
                          if margin < 0.5 else math.inf)
            return
        # Raised once: the way back passes through the same bad values and
        # must not be stopped.  Armed again once back within the tolerance.
        if not self.alarm:
            self.alarm = True
            raise UnstableIntegrationError(
                self.explain(number, drift, self.limit))


