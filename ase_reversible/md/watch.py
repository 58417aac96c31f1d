"""What a run depends on besides positions and momenta, watched every step.

Exact reversal retraces a step only under the dynamics the step was taken
with: the same forces (calculator, its parameters, atomic numbers, cell,
pbc), masses and constraints.  Users change these between runs as a matter
of course, so the integrator compares them with a snapshot before every
step that code outside it may have preceded (every run's first step; with
observers or a caller of ``irun``, every step) and either takes a change
(the anchor of reversal moves to that point) or refuses it.  Nothing is
ignored.

The comparison is on the per-step path, so it is one chain of cheap tests:
identities first (the calculator, the constraints), then the raw bytes of
the cell and pbc, numbers and masses by :func:`same_values`, and the
calculator's parameter dict by ``==``.  Naming what changed, with exact
comparisons, happens only once something has.  In the step-cost benchmark
(docs/benchmarks.md, "Cost of the per-step checks") it took 3.5 µs per
step for 144 atoms under asap3 EMT and 67 µs for 32,000, timed inside the
steps, at most 1% of a step; with and without it the step times were
within the noise of the rounds in all 13 cases.

Also here: what an edit may not set (NaN or infinite positions, momenta
or cell entries), and :class:`AnchorMoves`, which collapses the warnings
of a change repeated at every step of a run into two.

What it cannot see, and the user guide says so: a constraint object
modified in place (set the constraints again instead), and calculator
settings changed other than through ``calc.parameters`` (``calc.set``
writes there; asap3 calculators have no ASE parameters: attach a new
calculator instead).
"""

from __future__ import annotations

import copy
import functools
import operator
import warnings

import numpy as np

from ..errors import AnchorMovedWarning, NonFiniteStateError
from ..purity import calculator_members, mixture

#: The change reported for a calculator replaced by an equal one: same
#: class, equal parameters, mixing nothing.  Its forces are the same
#: function of the positions, so reversal is unaffected.
EQUAL_CALCULATOR = 'an equal calculator'


class SystemWatch:
    """Snapshot of the atoms' dynamics-defining properties.

    Parameters
    ----------
    atoms : ase.Atoms
        The atoms whose calculator, constraints, cell, pbc, atomic numbers
        and masses are recorded.
    """

    def __init__(self, atoms):
        self.take(atoms)

    def take(self, atoms):
        """Record the atoms' present properties as the accepted ones."""
        self.n_atoms = len(atoms)
        self.calc = atoms.calc
        members = calculator_members(self.calc)
        self._parameters = [_ParameterSnapshot(c) for c in members]
        self._weights = [(c, copy.deepcopy(mixture(c)[1]))
                         for c in members if mixture(c) is not None]
        self._calculator_checks = tuple(
            [s.same for s in self._parameters if s.values is not None]
            + [functools.partial(_same_weights, c, w)
               for c, w in self._weights])
        self._constraints = tuple(atoms.constraints)
        self._cell = atoms.cell.array.tobytes()
        self._pbc = atoms.pbc.tobytes()
        self._numbers = atoms.arrays['numbers'].copy()
        masses = atoms.arrays.get('masses')
        self._masses = None if masses is None else masses.copy()
        self._effective_masses = atoms.get_masses()

    def accept_cell(self, atoms):
        """Take the atoms' present cell as the accepted one (a dynamics
        that moves the cell itself, after checking it is the one it
        showed)."""
        self._cell = atoms.cell.array.tobytes()

    def changes(self, atoms) -> list:
        """Names of what differs from the snapshot; empty if nothing.

        Returns phrases such as ``'the cell'`` or ``"the calculator's
        parameters (epsilon)"``, for messages.
        """
        if self._unchanged(atoms):
            return []
        return self._changes(atoms)

    def _unchanged(self, atoms) -> bool:
        # The per-step path: one chain of cheap tests, nothing allocated
        # beyond a few short byte strings.
        if len(atoms) != self.n_atoms or atoms.calc is not self.calc:
            return False
        for same in self._calculator_checks:
            if not same():
                return False
        if not _same_objects(atoms.constraints, self._constraints):
            return False
        masses = atoms.arrays.get('masses')
        return (atoms.cell.array.tobytes() == self._cell
                and atoms.pbc.tobytes() == self._pbc
                and same_values(atoms.arrays['numbers'], self._numbers)
                and (masses is None if self._masses is None else
                     masses is not None and same_values(masses,
                                                        self._masses)))

    def _changes(self, atoms) -> list:
        if len(atoms) != self.n_atoms:
            return ['the number of atoms']
        changed = []
        if atoms.calc is not self.calc:
            changed.append(EQUAL_CALCULATOR if self._equal_to(atoms.calc)
                           else 'the calculator')
        else:
            for snapshot in self._parameters:
                if not snapshot.same():
                    changed.append(snapshot.describe())
            for calc, weights in self._weights:
                if not _same_weights(calc, weights):
                    changed.append(f"{type(calc).__name__}'s weights")
        # The members, not the list: del atoms.constraints makes a new one.
        if not _same_objects(atoms.constraints, self._constraints):
            changed.append('the constraints')
        if atoms.cell.array.tobytes() != self._cell:
            changed.append('the cell')
        if atoms.pbc.tobytes() != self._pbc:
            changed.append('pbc')
        if not np.array_equal(atoms.arrays['numbers'], self._numbers):
            changed.append('the atomic numbers')
        # Stored or not, equal values are no change (set_masses(m) after
        # set_masses(None) stores what the defaults were).
        if not np.array_equal(atoms.get_masses(), self._effective_masses):
            changed.append('the masses')
        elif not changed:
            masses = atoms.arrays.get('masses')
            self._masses = None if masses is None else masses.copy()
        return changed


    def _equal_to(self, calc) -> bool:
        # Only a plain ASE Calculator is defined by its parameters: a
        # mixing one also has weights, asap3's have no parameters at all.
        from ase.calculators.calculator import Calculator
        old = self._parameters[0] if self._parameters else None
        return (old is not None and old.values is not None
                and type(calc) is type(old.calc)
                and isinstance(calc, Calculator)
                and mixture(calc) is None
                and _equal(dict(calc.parameters), old.values))


class AnchorMoves:
    """The anchor-moved warnings of one run, collapsed.

    An observer that wraps the atoms or rescales the momenta changes them
    at every step, and every step's change is taken: one warning per step
    would bury the output, and Python's warning filter cannot collapse
    them (each text names another time).  So the first change of a kind
    is warned at once, and repeats are counted and summed up in one
    warning when the run ends (or fails, or its ``irun`` is closed).
    """

    def __init__(self, name):
        self.name = name
        #: kind -> [repeats, time of the first, time of the last (fs)]
        self._seen = {}

    def warn(self, kind, message, stacklevel, time):
        """Issue ``message`` if no change of ``kind`` (a phrase such as
        ``'the cell changed outside ReversibleVerlet'``) was warned in this
        run, else count it; ``time`` (fs) is where the anchor now is."""
        seen = self._seen.get(kind)
        if seen is None:
            self._seen[kind] = [0, time, time]
            warnings.warn(message, AnchorMovedWarning,
                          stacklevel=stacklevel + 1)
        else:
            seen[0] += 1
            seen[2] = time

    def summarise(self, stacklevel):
        """One warning per kind of change that recurred in the run."""
        for kind, (repeats, first, last) in self._seen.items():
            if repeats:
                warnings.warn(
                    f'The change warned at time {first:.6g} fs ({kind}) was '
                    f'made again at {repeats} more '
                    f'step{"s" if repeats > 1 else ""} of this run and taken '
                    'each time: the anchor of reversal moved at every one, '
                    f'last at time {last:.6g} fs; reversal now leads back '
                    'there, not beyond. Code run between the steps (an '
                    'observer that wraps the atoms or rescales the momenta) '
                    'makes such changes: to analyse the atoms without '
                    f'changing the run of {self.name}, work on a copy '
                    '(atoms.copy()).',
                    AnchorMovedWarning, stacklevel=stacklevel + 1)
        self._seen.clear()


def check_finite_cell(atoms, advice):
    """Raise ``ValueError`` (with ``advice``) if the cell holds a NaN or an
    infinity: otherwise the change would be taken and the first force call
    would fail with a message that does not name the cell."""
    cell = atoms.cell.array
    if not np.isfinite(cell).all():
        raise ValueError(
            f'The cell has non-finite entries (NaN or infinite): '
            f'{cell.tolist()}. {advice}')


def refuse_unholdable_values(atoms):
    """Refuse atoms with a NaN or infinite position, momentum or cell entry
    (:class:`~ase_reversible.NonFiniteStateError`, ``ValueError``), naming
    the atom, before a constructor changes anything."""
    check_finite_cell(atoms, 'Set a finite cell (atoms.set_cell).')
    problem = non_finite(atoms)
    if problem is not None:
        name = 'positions' if 'position' in problem else 'momenta'
        raise NonFiniteStateError(
            f'The atoms have non-finite {name}: {problem}. Set finite '
            'positions and momenta before constructing the integrator.')


def non_finite(atoms):
    """What is wrong with the atoms' positions or momenta, or None.

    A phrase such as ``'the position of atom 3 is NaN'``, naming the first
    atom with a NaN or infinite position (else momentum) and how many
    more have one; None if all are finite.  Not on the per-step path: it
    runs only once an edit has been seen.
    """
    for name, what in (('positions', 'position'), ('momenta', 'momentum')):
        values = atoms.arrays.get(name)
        if values is None:
            continue
        finite = np.isfinite(values)
        if finite.all():
            continue
        rows = np.flatnonzero(~finite.reshape(len(values), -1).all(axis=1))
        atom = int(rows[0])
        value = values[atom][~finite[atom]][0]
        text = (f'the {what} of atom {atom} is '
                f'{"NaN" if np.isnan(value) else "infinite"}')
        if len(rows) > 1:
            more = len(rows) - 1
            text += (f' (and {more} more atom{"s" if more > 1 else ""} with '
                     f'a non-finite {what})')
        return text
    return None


def same_values(a, b) -> bool:
    """Whether two float arrays of one shape hold the same values.

    The per-step test of positions and momenta.  Small arrays are compared
    as raw bytes (a quarter of ``np.array_equal``'s cost at 13 atoms; a
    -0.0 written over 0.0 then counts as an edit, which is taken and snaps
    to the same integers); large ones elementwise, where making byte
    strings would cost more than the comparison.
    """
    if a.size <= _BYTES_COMPARE_LIMIT:
        return a.tobytes() == b.tobytes()
    return bool((a == b).all())


#: Elements up to which :func:`same_values` compares bytes.  Measured on the
#: development machine: at 39 elements bytes take 0.3 µs against 4 µs for
#: ``(a == b).all()``; at 12,000 elements 9 µs against 6 µs.
_BYTES_COMPARE_LIMIT = 1024


class _ParameterSnapshot:
    """A deep copy of one calculator's ``parameters`` dict, if it has one."""

    def __init__(self, calc):
        self.calc = calc
        params = getattr(calc, 'parameters', None)
        self.values = (copy.deepcopy(dict(params))
                       if isinstance(params, dict) else None)

    def same(self) -> bool:
        if self.values is None:
            return True
        params = self.calc.parameters
        try:
            # Scalars, strings and tuples: one C-level dict comparison.
            return bool(params == self.values)
        except (ValueError, TypeError):
            # Arrays among the values: compare them exactly.
            return _equal(dict(params), self.values)

    def describe(self) -> str:
        params = dict(self.calc.parameters)
        keys = sorted(set(params) | set(self.values), key=str)
        names = [str(k) for k in keys
                 if k not in params or k not in self.values
                 or not _equal(params[k], self.values[k])]
        name = type(self.calc).__name__
        return f"{name}'s parameters ({', '.join(names) or 'in place'})"


def _equal(a, b) -> bool:
    """Exact equality of parameter values: arrays elementwise, NaN == NaN."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and np.array_equal(a, b, equal_nan=(
            a.dtype.kind in 'fc' and b.dtype.kind in 'fc'))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    try:
        return bool(a == b) or (a != a and b != b)
    except (ValueError, TypeError):
        return False


def _same_objects(now, then) -> bool:
    return len(now) == len(then) and all(map(operator.is_, now, then))


def _same_weights(calc, weights) -> bool:
    return _equal(mixture(calc)[1], weights)
