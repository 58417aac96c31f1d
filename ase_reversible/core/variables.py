"""Exact variables: int64 counts of a quantum, updated with rollback.

A dynamics declares its variables by name (``'position'``, ``'momentum'``,
a thermostat's ``'thermostat_position'`` ...); each is an
:class:`ExactVariable` of any shape.  Side state that a dynamics keeps
besides (a cache, an information buffer) takes part in a step's
checkpoint and rollback by offering the same two methods.
"""

from __future__ import annotations

import itertools

import numpy as np

from .codec import LIMIT, check_range, decode

#: Labels of values: every update gets a new one, a rollback restores the
#: old one, so a cache keyed by a label is valid exactly while its value is.
_labels = itertools.count()

_STEP_ADVICE = ('The step was not taken. If the system is fine, construct the '
                'integrator with a larger quantum; if it is blowing up, use a '
                'smaller time step.')


class ExactVariable:
    """One fixed-point variable updated without allocations.

    Holds the int64 counts and their exact float64 image ``counts *
    quantum``.  Three buffers rotate -- the value at the last
    :meth:`checkpoint`, the current value, and the one being written -- so
    an update never overwrites the checkpoint, and :meth:`rollback` puts it
    back without copying anything.

    Each buffer carries an upper bound on its largest ``|count|``: an update
    adds the increment's largest magnitude to it and checks the sum itself
    only when the bound reaches ``LIMIT``.  With the default head room that
    is rare, so most updates skip two passes over the array.

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
        quantum = self.quantum
        self._ints = [np.array(ints, dtype=np.int64)]
        self._ints += [np.empty_like(self._ints[0]) for _ in range(2)]
        self._floats = [decode(self._ints[0], quantum)]
        self._floats += [np.empty_like(self._floats[0]) for _ in range(2)]
        self._bounds = [float(np.abs(self._ints[0]).max(initial=0)), 0.0, 0.0]
        self._labels = [next(_labels), None, None]
        self._current = self._checkpoint = 0

    @property
    def ints(self) -> np.ndarray:
        """The current counts (int64); overwritten by later updates."""
        return self._ints[self._current]

    @property
    def floats(self) -> np.ndarray:
        """The current exact image in float64; overwritten by later updates."""
        return self._floats[self._current]

    @property
    def label(self) -> int:
        """Equal labels mean equal values (see the class docstring)."""
        return self._labels[self._current]

    def add_integers(self, r: np.ndarray):
        """Add the integer-valued float array ``r`` (not modified).

        ``r``: float64 of the variable's shape, in quanta, already rounded.
        Raises :class:`~ase_reversible.QuantumRangeError` and leaves the
        value unchanged if an element of ``r`` or of the sum is non-finite
        or out of range.
        """
        r_max = max(r.max(initial=0.0), -r.min(initial=0.0))
        if not r_max < LIMIT:  # also NaN
            check_range(r, self.name + ' increment', self.quantum,
                        _STEP_ADVICE)
        spare = 3 - self._current - self._checkpoint if \
            self._current != self._checkpoint else (self._current + 1) % 3
        new = self._ints[spare]
        np.copyto(new, r, casting='unsafe')
        np.add(self._ints[self._current], new, out=new)
        # |counts| and |r| are below 2**53, so the int64 sum cannot wrap.
        # Float sums of whole numbers round monotonically, so the bound
        # never falls below LIMIT when the true sum could reach it.
        bound = self._bounds[self._current] + r_max
        if not bound < LIMIT:
            bound = max(new.max(initial=0), -new.min(initial=0))
            if not bound < LIMIT:
                check_range(new, self.name, self.quantum, _STEP_ADVICE)
        self._bounds[spare] = float(bound)
        np.multiply(new, self.quantum, out=self._floats[spare])
        self._labels[spare] = next(_labels)
        self._current = spare

    def checkpoint(self):
        """Remember the current value for :meth:`rollback`."""
        self._checkpoint = self._current

    def rollback(self):
        """Return to the value at the last :meth:`checkpoint`."""
        self._current = self._checkpoint
