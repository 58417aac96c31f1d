"""The change contract of every reversible dynamics: a change made around a
run (an edit of the positions or momenta, the calculator, the constraints,
the cell, the masses, a setting of the dynamics) is taken exactly -- the
anchor of reversal moves there, with an
:class:`~ase_reversible.AnchorMovedWarning` -- or refused, leaving all as
it was.  What is compared to find the changes is :mod:`.watch`'s.
"""

from __future__ import annotations

import warnings

import numpy as np
from ase import units

from ..core.codec import LIMIT
from ..errors import (AnchorMovedWarning, NonFiniteStateError,
                      QuantumRangeError, UnsupportedConstraintError)
from ..purity import calculator_members, discard_results, force_provider
from .checks import checked_masses, refuse_calculator_without_forces
from .constraints import constraint_projection
from .watch import EQUAL_CALCULATOR, check_finite_cell, non_finite, \
    same_values


def forget_results(calc):
    """Drop every result and neighbour list ``calc`` and the calculators it
    mixes keep from before a change."""
    # ASE's Calculator.set keeps results (and ASE's LennardJones its
    # neighbour list) from before the change: the first kick after it
    # would use them.  reset() is ASE's way to drop all of that.
    for member in calculator_members(calc):
        if callable(getattr(member, 'reset', None)):
            member.reset()
        else:
            discard_results(member)


def refuse_rigid_change(name, changes):
    """Refuse ``changes`` (names of what changed) around a run of rigid
    bodies: only edits of positions and momenta are taken there."""
    raise UnsupportedConstraintError(
        f'Changed outside {name} since the last step: {", ".join(changes)}. '
        'A run of rigid molecules takes edits of positions and momenta '
        'only: undo the change to go on (nothing was changed; reversal '
        f'still leads back exactly), or construct a new {name} for the '
        'changed system.')


class ChangeContract:
    """The change contract's part of
    :class:`~ase_reversible.md.base.ReversibleDynamics`: ``_sync`` before
    every step takes or refuses what changed since the last one."""

    #: The running run's :class:`~.watch.AnchorMoves`, None between runs.
    _moves = None

    def _sync(self):
        """Take or refuse changes made around the run (see :mod:`.watch`)."""
        atoms = self.atoms
        changes = self._watch.changes(atoms)
        if changes and self._take_changes(changes):
            return
        momenta = atoms.arrays.get('momenta')
        if (same_values(atoms.arrays['positions'], self._shown_positions())
                and momenta is not None
                and same_values(momenta, self.system.shown_momenta())):
            return
        self._install(self._edited_counts(atoms, self.system.project))
        name = type(self).__name__
        self._anchor_moved(
            f'positions or momenta changed outside {name}',
            f'Positions or momenta were changed outside {name}. The change '
            'was taken and snapped to the grid; reversal now leads back to '
            'this point (time '
            f'{self.get_time() / units.fs:.6g} fs), not beyond.',
            stacklevel=3)

    def _shown_positions(self):
        """The positions the atoms show of the exact state, ``[n_atoms,
        3]`` (not to be modified)."""
        return self.system.shown_positions()

    def _anchor_moved(self, kind, message, stacklevel):
        """Warn that the anchor moved (:class:`AnchorMovedWarning`); within
        a run, a ``kind`` already warned is counted for the run's summary
        instead (:class:`~.watch.AnchorMoves`)."""
        if self._moves is None:
            warnings.warn(message, AnchorMovedWarning,
                          stacklevel=stacklevel + 1)
        else:
            self._moves.warn(kind, message, stacklevel + 1,
                             self.get_time() / units.fs)

    def _take_changes(self, changes):
        """Take a change of the dynamics, or refuse it leaving all as was.

        Everything that can refuse runs before anything is replaced.
        Returns True if the anchor moved (the state was re-installed),
        False for a calculator replaced by an equal one.
        """
        atoms = self.atoms
        if self.system.layout is not None and changes != [EQUAL_CALCULATOR]:
            refuse_rigid_change(type(self).__name__, changes)
        if len(atoms) != len(self.system.atom_masses_n1):
            raise ValueError('The number of atoms changed; construct a new '
                             f'{type(self).__name__} for the new system (or '
                             'put the atoms back to continue this run).')
        if atoms.calc is None:
            raise RuntimeError('The atoms lost their calculator; attach one '
                               '(atoms.calc = ...) before running.')
        refuse_calculator_without_forces(atoms.calc, 'running')
        check_finite_cell(atoms, 'Set it back (atoms.set_cell) to go on: '
                          'nothing was changed.')
        # A system without rigid bodies refuses a rigid constraint added
        # in mid-run (it would need other variables), never ignores it.
        project = constraint_projection(atoms,
                                        rigid=self.system.layout is not None)
        masses_n = checked_masses(atoms)
        # Before the force provider is chosen: a probe would call the
        # calculator at these positions.
        counts = self._edited_counts(atoms, project)
        # Any change may alter how pure the forces are (a new calculator or
        # cut-off, atoms now near a periodic face): choose again.
        purity = force_provider(atoms, *self._purity_choice)
        if changes == [EQUAL_CALCULATOR]:
            self.system.purity = purity
            self._watch.take(atoms)
            self.system.kick.forget()
            return False
        forget_results(atoms.calc)
        self.system.set_dynamics(masses_n, project, purity)
        self.masses = self.system.atom_masses_n1
        self._watch.take(atoms)
        self.engine.set_dt(self.engine.dt)  # coefficients use the masses
        self._install(counts)
        name, changed = type(self).__name__, ", ".join(changes)
        self._anchor_moved(
            f'{changed} changed outside {name}',
            f'Changed outside {name} since the last step: {changed}. The '
            'change was taken (positions and '
            'momenta snapped to the grid, momenta projected onto the '
            'constraints); reversal now leads back to this point (time '
            f'{self.get_time() / units.fs:.6g} fs), not beyond. To retrace '
            'further back exactly, undo the change when you get here.',
            stacklevel=4)
        return True

    def _change_setting(self, what, assign):
        """Take a new setting of the dynamics (``assign()`` makes it) from
        the next step on; the anchor moves here, with an
        :class:`AnchorMovedWarning` naming ``what`` if steps were taken."""
        self._sync()
        taken = self.engine.steps_since_anchor
        assign()
        self.engine.set_dt(self.engine.dt)  # prepare with the new setting
        self._install(self.engine.snapshot())
        if taken:
            changed = f'{what} of {type(self).__name__} changed'
            self._anchor_moved(
                f'the {changed}', f'The {changed} after {taken} steps; '
                'reversal now leads back to this point (time '
                f'{self.get_time() / units.fs:.6g} fs), not beyond.',
                stacklevel=3)

    def _edited_counts(self, atoms, project):
        """The counts of positions and momenta set on the atoms between
        runs, or, if the grid cannot hold them (NaN, infinite, out of
        range), the last exact state put back on the atoms and an error
        that says so: the values the edit replaced are gone, and without
        them neither the run nor its reversal could go on."""
        problem, error = non_finite(atoms), NonFiniteStateError
        advice = 'To change the state, set finite values.'
        if problem is None:
            error = QuantumRangeError
            advice = ('To change the state, set values within the range of '
                      'the grid (dyn.grid); a larger range needs a new '
                      'integrator with a larger position_quantum or '
                      'momentum_quantum.')
            # A virtual momentum (ReversibleNose) is not range-checked
            # when made: an out-of-range float casts to a count outside
            # (-LIMIT, LIMIT), refused below.
            with np.errstate(invalid='ignore'):
                try:
                    counts = self._encode(atoms, project)
                except QuantumRangeError as refused:
                    problem = 'the ' + str(refused).removesuffix(
                        ' Choose a larger quantum.')
                else:
                    problem = next(
                        (f'a {name} is outside the fixed-point range'
                         for name, c in counts.items()
                         if not ((c > -LIMIT) & (c < LIMIT)).all()), None)
            if problem is None:
                return counts
        self.system.show()
        raise error(
            f'Refused an edit made outside {type(self).__name__} since the '
            f'last step: {problem.rstrip(".")}. The fixed-point grid cannot '
            'hold it, and the values it replaced are gone, so the atoms were '
            'put back to the last exact state (positions and momenta at time '
            f'{self.get_time() / units.fs:.6g} fs): reverse() and further '
            'runs go on from there as if the edit had not been made. '
            + advice)

    def _encode(self, atoms, project):
        """The counts of every exact variable the atoms show, by name,
        on this dynamics' grid (``project``: the constraint projection)."""
        return self.system.encode(atoms, project)
