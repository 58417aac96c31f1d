"""Exact variables: whole-number counts of a quantum, updated with rollback.

A dynamics declares its variables by name (``'position'``, ``'momentum'``,
a thermostat's ``'thermostat_position'`` ...); each is an
:class:`ExactVariable` of any shape.  Side state that a dynamics keeps
besides (a cache, an information buffer) takes part in a step's
checkpoint and rollback by offering the same two methods.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .codec import LIMIT, check_range, decode, round_odd

#: Labels of values: every update gets a new one, a rollback restores the
#: old one, so a cache keyed by a label is valid exactly while its value is.
_labels = itertools.count()

_STEP_ADVICE = ('The step was not taken. If the system is fine, construct the '
                'integrator with a larger quantum; if it is blowing up, use a '
                'smaller time step.')


class ExactVariable:
    """One fixed-point variable updated without allocations.

    Holds the counts and their exact float64 image ``counts * quantum``,
    made when it is first read.
    The counts are whole numbers below ``LIMIT = 2**53`` in magnitude, kept
    in float64, where such numbers and their sums below ``LIMIT`` are exact
    as in int64: an update is then one float addition, with no conversion
    between integer and float arrays (the three such passes of an int64
    update cost twice the arithmetic at a hundred atoms and three times
    at thousands).  :attr:`ints` gives them as int64.

    An update never overwrites the value at the last :meth:`checkpoint`,
    so :meth:`rollback` puts it back without copying anything.  The first
    update after a checkpoint writes another buffer (the one the
    checkpoint before used, so that a run alternates between two); later
    ones add in place, unless the sum may leave the range, when they
    write the third buffer so that a refused update leaves the value as
    it was.

    Each buffer carries an upper bound on its largest ``|count|``: an update
    adds the increment's largest magnitude to it and checks the sum itself
    only when the bound reaches ``LIMIT``.  With the default head room that
    is rare, so most updates skip a pass over the array.

    Parameters
    ----------
    name : str
        The variable's name, for error messages (``'position'``).
    ints : int64 array, any shape (``[n_atoms, 3]`` for atoms)
        Initial counts, all below ``LIMIT`` in magnitude.
    quantum : float
        The power-of-two quantum.

    Attributes
    ----------
    label : int
        Changes with every update and returns with a rollback: equal labels
        mean equal values.
    """

    def __init__(self, name: str, ints: np.ndarray, quantum: float):
        self.name = name
        self.quantum = quantum
        self.reset(ints)

    def reset(self, ints: np.ndarray):
        """Start again from ``ints`` (copied), forgetting the checkpoint."""
        ints = np.asarray(ints, dtype=np.int64)
        counts = ints.astype(np.float64)  # exact: |ints| < LIMIT
        self._counts = [counts] + [np.empty_like(counts) for _ in range(2)]
        self._floats = [decode(ints, self.quantum)]
        self._floats += [np.empty_like(counts) for _ in range(2)]
        # Whether each buffer's image is made: only when it is read.
        self._imaged = [True, False, False]
        self._scratch = np.empty_like(counts)
        self._bounds = [_max_abs(counts, self._scratch), 0.0, 0.0]
        self._labels = [next(_labels), None, None]
        self._current = self._checkpoint = 0
        self._spare = 1  # the buffer the next update from a checkpoint uses
        self.label = self._labels[0]

    @property
    def ints(self) -> np.ndarray:
        """The current counts as a new int64 array."""
        return self._counts[self._current].astype(np.int64)

    @property
    def counts(self) -> np.ndarray:
        """The current counts, float64 whole numbers (not to be modified):
        ``counts * (quantum * f)`` is bitwise ``floats * f`` (the quantum
        is a power of two), without the pass that makes the image."""
        return self._counts[self._current]

    @property
    def floats(self) -> np.ndarray:
        """The current exact image in float64; overwritten by later updates."""
        current = self._current
        if not self._imaged[current]:
            np.multiply(self._counts[current], self.quantum,
                        out=self._floats[current])
            self._imaged[current] = True
        return self._floats[current]

    def write_floats(self, out: np.ndarray):
        """Write the current exact image into ``out`` (float64, the
        variable's shape): in one pass, where copying :attr:`floats` could
        take two."""
        np.multiply(self._counts[self._current], self.quantum, out=out)

    @property
    def bound(self) -> float:
        """An upper bound on the largest ``|count|`` of the current value."""
        return self._bounds[self._current]

    def add_rounded(self, y):
        """Add ``round_odd(y)``: ``y`` in quanta, of the variable's shape
        (a float for a variable of one entry).  The rounded increment's
        own magnitude is the bound, so no pass over it is needed: for the
        few-entry variables of thermostats and barostats."""
        r = round_odd(np.array(y, dtype=np.float64, ndmin=1))
        self.add_integers(r, float(np.abs(r).max()))

    def add_integers(self, r: np.ndarray, r_max=None) -> float:
        """Add the integer-valued float array ``r`` (not modified).

        ``r``: float64 of the variable's shape, in quanta, already rounded.
        ``r_max``: an upper bound on ``max |r|`` that the caller knows (as
        returned here for the same ``r`` before), or None.  Returns the
        bound used.  Raises :class:`~ase_reversible.QuantumRangeError` and
        leaves the value unchanged if an element of ``r`` or of the sum is
        non-finite or out of range.
        """
        if r_max is None:
            r_max = _bound_abs(r, self._scratch)
        if not r_max < LIMIT:
            r_max = _max_abs(r, self._scratch)
            if not r_max < LIMIT:  # also NaN
                check_range(r, self.name + ' increment', self.quantum,
                            _STEP_ADVICE)
        current = self._current
        bound = self._bounds[current] + r_max
        if current != self._checkpoint and bound < LIMIT:
            # Nothing needs the current value back (a rollback returns to
            # the checkpoint) and the sum cannot leave the range: added in
            # place, so a step touches two buffers, not three.
            spare = current
        elif current != self._checkpoint:
            spare = 3 - current - self._checkpoint
        else:
            spare = self._spare if self._spare != current else \
                (current + 1) % 3
            self._spare = current
        new = self._counts[spare]
        np.add(self._counts[current], r, out=new)
        # Whole numbers below 2**53 add exactly; a sum at or beyond it may
        # round, but never back below LIMIT (rounding is monotonic and
        # LIMIT a float), so the bound and the check below still see it.
        if not bound < LIMIT:
            bound = _max_abs(new, self._scratch)
            if not bound < LIMIT:
                check_range(new, self.name, self.quantum, _STEP_ADVICE)
        self._bounds[spare] = bound
        self._imaged[spare] = False
        self._labels[spare] = self.label = next(_labels)
        self._current = spare
        return r_max

    def checkpoint(self):
        """Remember the current value for :meth:`rollback`."""
        self._checkpoint = self._current

    def rollback(self):
        """Return to the value at the last :meth:`checkpoint`."""
        self._current = self._checkpoint
        self.label = self._labels[self._current]


_maximum = np.maximum.reduce
_dot = np.dot

#: Elements up to which :func:`_bound_abs` takes the Euclidean norm: a
#: BLAS dot product, which OpenBLAS runs on one thread up to 10,000
#: elements (beyond, handing work to threads costs more than it saves).
#: Measured on the development machine: 0.8 µs against 1.8 µs for
#: max |a| at 39 elements, 1.1 against 2.8 at 3000.
_NORM_LIMIT = 10_000


def _bound_abs(a, scratch) -> float:
    """An upper bound on ``max |a|`` in one pass, NaN or inf if ``a`` holds
    a non-finite value or overflows it."""
    if a.size > _NORM_LIMIT:
        return _max_abs(a, scratch)
    flat = a.reshape(-1)
    # The Euclidean norm bounds every element; the factor covers the
    # rounding of the sum of squares.
    return math.sqrt(float(_dot(flat, flat))) * (1.0 + 2.0**-30)


def _max_abs(a, scratch) -> float:
    """``max |a|`` (0 for an empty array, NaN if ``a`` holds one), through
    ``scratch`` of ``a``'s shape: one pass fewer than ``max`` and ``min``."""
    return float(_maximum(np.abs(a, out=scratch), axis=None, initial=0.0))
