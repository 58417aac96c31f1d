"""The contract with the user, drawn at random: sequences of runs,
reversals and user actions on real ASE calculators, every step of the
contract (tests/test_contract.py's docstring) checked against a small
model that does not read ``dyn.anchor``.  Exactness is ``np.array_equal``
on positions and momenta (and the int64 state), never a tolerance."""

import warnings

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase.constraints import FixAtoms, FixBondLengths
from hypothesis import HealthCheck, given, settings, strategies as st

from ase_reversible import (NonFiniteStateError, ReversibleVerlet,
                            UnsupportedConstraintError)
from conftest import DT, argon_cluster, ase_lj
from contract import (assert_state_is_anchor, copper, moves,
                      run_forbidding_anchor_moves, same_fixed_point_state)
from exactness import (assert_atoms_show_committed_state, assert_same_state,
                       snapshot)
from tiers import SLOW


# -- 2. property: random sequences of runs, reversals and user actions -------
#
# A small model follows each example, independent of dyn.anchor:
#   anchor_x, anchor_p  positions and momenta reversal must lead back to;
#   net                 signed steps taken since the anchor, counted positive
#                       in the direction of +|dt| (a run of k steps adds
#                       k * sign(dt); reversing only flips the sign of dt).
# Every action says what the contract makes of it -- TAKEN (exactly one
# AnchorMovedWarning, the anchor moves to the snapped state, net = 0),
# SILENT (no AnchorMovedWarning, nothing moves) or refused (checked inside
# the action, which then undoes the change).  Before every action other
# than a run, |net| steps in the right direction must land bit for bit on
# the model's anchor and |net| steps out again on the state left; the same
# back to the anchor ends the example.  Checking each stretch when it may
# end matters: most actions move the anchor, and a miss in a stretch that
# a later anchor closed would never be seen at the end.

TAKEN, SILENT = 'taken', 'silent'
DT_SIZES_FS = (2, 4, 5)


def build(system, seed):
    if system == 'argon':
        atoms = argon_cluster(2, 80, seed)
        atoms.calc = ase_lj()
    else:
        atoms = copper(seed)
    return atoms


def equal_calculator(calc):
    """A fresh calculator of the same class with equal parameters."""
    return type(calc)(**calc.parameters)


def other_calculator(calc):
    """A fresh calculator of the same class whose forces differ."""
    if isinstance(calc, LennardJones):
        return LennardJones(**{**calc.parameters,
                               'sigma': 1.01 * calc.parameters['sigma']})
    return EMT(asap_cutoff=not calc.parameters.get('asap_cutoff', False))


def changed_by(atoms, edit):
    """Apply ``edit(atoms)``; TAKEN if positions or momenta changed."""
    before = snapshot(atoms)
    edit(atoms)
    after = snapshot(atoms)
    same = (np.array_equal(before[0], after[0])
            and np.array_equal(before[1], after[1]))
    return SILENT if same else TAKEN


class Example:
    """One drawn system, its integrator and the model of the contract."""

    def __init__(self, system, seed):
        self.atoms = build(system, seed)
        self.dyn = ReversibleVerlet(self.atoms, DT)
        self.net = 0
        self.set_anchor()

    def set_anchor(self):
        self.anchor = snapshot(self.atoms)
        self.anchor_time = self.dyn.get_time()
        self.net = 0

    @property
    def sign(self):
        return 1 if self.dyn.dt > 0 else -1

    # Each action changes something and returns TAKEN or SILENT: what the
    # action and the run(0) after it must do to the anchor.  A refused
    # change is checked and undone inside the action, which then returns
    # SILENT: the undone change must leave no trace.

    def run(self, steps):
        self.dyn.run(steps)
        self.net += steps * self.sign
        return SILENT

    def reverse(self):
        self.dyn.reverse()
        return SILENT

    def negate_dt(self):
        self.dyn.dt = -self.dyn.dt
        return SILENT

    def resize_dt(self, fs):
        size = fs * units.fs
        if size == abs(self.dyn.dt):
            return SILENT
        self.dyn.dt = self.sign * size
        if self.net == 0:  # no step since the anchor: nothing to move
            return SILENT
        return TAKEN

    def move_atom(self, atom, shift):
        def edit(atoms):
            positions = atoms.get_positions()
            positions[atom] += shift
            atoms.positions = positions
        return changed_by(self.atoms, edit)

    def scale_momentum(self, atom, factor):
        def edit(atoms):
            momenta = atoms.get_momenta()
            momenta[atom] *= factor
            atoms.set_momenta(momenta, apply_constraint=False)
        return changed_by(self.atoms, edit)

    def heavier(self, atom):
        masses = self.atoms.get_masses()
        masses[atom] *= 2.0
        self.atoms.set_masses(masses)
        return TAKEN

    def zero_mass(self, atom):
        # Undone exactly as it was: no masses array if there was none.
        # (Undoing with equal values in another form is a regression test.)
        accepted = self.atoms.arrays.get('masses')
        if accepted is not None:
            accepted = accepted.copy()  # set_masses writes in place
        bad = self.atoms.get_masses()
        bad[atom] = 0.0
        self.atoms.set_masses(bad)
        self.refused(ValueError, 'mass')
        self.atoms.set_masses(accepted)  # None deletes the array
        return SILENT

    def swap_element(self, atom):
        # Argon <-> krypton keeps ASE's LJ forces but changes the mass;
        # copper <-> nickel changes EMT's forces.
        swap = {18: 36, 36: 18, 29: 28, 28: 29}
        numbers = self.atoms.get_atomic_numbers()
        numbers[atom] = swap[numbers[atom]]
        self.atoms.set_atomic_numbers(numbers)
        return TAKEN

    def fix_atom(self, atom):
        self.atoms.set_constraint(list(self.atoms.constraints)
                                  + [FixAtoms(indices=[atom])])
        return TAKEN

    def unconstrain(self):
        if not self.atoms.constraints:
            return SILENT  # nothing to remove: no change made
        del self.atoms.constraints
        return TAKEN

    def bond_constraint(self, atom):
        accepted = self.atoms.constraints
        self.atoms.set_constraint(
            list(accepted) + [FixBondLengths([(atom, (atom + 1) % 13)])])
        self.refused(UnsupportedConstraintError, 'FixBondLengths')
        self.atoms.set_constraint(accepted)  # undo: the very list accepted
        return SILENT

    def strain_cell(self):
        self.atoms.set_cell(1.001 * self.atoms.cell, scale_atoms=False)
        return TAKEN

    def wrap(self):
        return changed_by(self.atoms, lambda atoms: atoms.wrap())

    def calc_set(self, name):
        calc = self.atoms.calc
        changed = calc.set(**{name: 1.02 * calc.parameters[name]})
        assert changed
        return TAKEN

    def equal_calc(self):
        self.atoms.calc = equal_calculator(self.atoms.calc)
        return SILENT

    def other_calc(self):
        self.atoms.calc = other_calculator(self.atoms.calc)
        return TAKEN

    def calc_reset(self):
        self.atoms.calc.reset()
        return SILENT

    def remove_calc(self, fresh):
        calc = self.atoms.calc
        self.atoms.calc = None
        self.refused(RuntimeError, 'lost their calculator')
        self.atoms.calc = equal_calculator(calc) if fresh else calc
        return SILENT

    def edit_info(self):
        self.atoms.info['note'] = 'edited between runs'
        self.atoms.info.pop('reversible', None)
        return SILENT

    def unholdable_value(self, name, atom, value):
        # The overwritten values are gone: the integrator puts its last
        # exact state back itself, the anchor stays.
        before, anchor = snapshot(self.atoms), self.dyn.anchor
        self.atoms.arrays[name][atom, 1] = value
        with pytest.raises(NonFiniteStateError, match='put back'):
            self.dyn.run(0)
        assert_same_state(self.atoms, before)
        assert same_fixed_point_state(self.dyn.anchor, anchor)
        return SILENT

    def non_finite_cell(self):
        accepted = self.atoms.cell.copy()
        self.atoms.cell.array[0, 0] = np.nan
        self.refused(ValueError, 'cell has non-finite entries')
        self.atoms.set_cell(accepted)
        return SILENT

    def refused(self, error, match):
        """``run(0)`` raises ``error`` and changes neither state nor anchor."""
        before, anchor = snapshot(self.atoms), self.dyn.anchor
        with pytest.raises(error, match=match):
            self.dyn.run(0)
        assert_same_state(self.atoms, before)
        assert same_fixed_point_state(self.dyn.anchor, anchor)

    # -- checks -----------------------------------------------------------

    def apply(self, action):
        """Do ``action`` and ``run(0)``; check the contract's verdict."""
        name, *args = action
        if name != 'run':
            # Each change may end a stretch of the run: check it now, as a
            # later change may move the anchor past it.
            self.round_trip()
        previous_anchor = self.dyn.anchor
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter('always')
            expected = getattr(self, name)(*args)
            self.dyn.run(0)
        messages = moves(record)
        assert_atoms_show_committed_state(self.dyn)
        if expected == TAKEN:
            assert len(messages) == 1, (action, messages)
            assert_state_is_anchor(self.dyn)
            self.set_anchor()
        else:
            assert messages == [], (action, messages)
            assert same_fixed_point_state(self.dyn.anchor, previous_anchor)

    def back_to_anchor(self):
        """Run |net| steps towards the anchor; demand it bit for bit."""
        if self.net:
            self.dyn.dt = (-1 if self.net > 0 else 1) * abs(self.dyn.dt)
        run_forbidding_anchor_moves(self.dyn, abs(self.net))
        assert_same_state(self.atoms, self.anchor)
        assert_state_is_anchor(self.dyn)
        # The clock adds up the steps of each size; changing the size can
        # round that sum another way, by an ulp.
        assert self.dyn.get_time() == pytest.approx(self.anchor_time,
                                                    rel=1e-12, abs=1e-12)

    def round_trip(self):
        """Back to the anchor and out again to here, bit for bit both ways.

        Leaves the state, the direction and the model as they were.
        """
        here, dt, net = snapshot(self.atoms), self.dyn.dt, self.net
        self.back_to_anchor()
        self.dyn.reverse()
        run_forbidding_anchor_moves(self.dyn, abs(net))
        assert_same_state(self.atoms, here)
        self.dyn.dt = dt


atom_index = st.integers(0, 12)  # valid in both systems
common_actions = [
    st.tuples(st.just('run'), st.integers(0, 8)),
    st.just(('reverse',)),
    st.just(('negate_dt',)),
    st.tuples(st.just('resize_dt'), st.sampled_from(DT_SIZES_FS)),
    st.tuples(st.just('move_atom'), atom_index,
              st.lists(st.floats(-0.05, 0.05), min_size=3, max_size=3)),
    st.tuples(st.just('scale_momentum'), atom_index, st.floats(0.5, 1.5)),
    st.tuples(st.just('heavier'), atom_index),
    st.tuples(st.just('zero_mass'), atom_index),
    st.tuples(st.just('swap_element'), atom_index),
    st.tuples(st.just('fix_atom'), atom_index),
    st.just(('unconstrain',)),
    st.tuples(st.just('bond_constraint'), atom_index),
    st.just(('equal_calc',)),
    st.just(('other_calc',)),
    st.just(('calc_reset',)),
    st.tuples(st.just('remove_calc'), st.booleans()),
    st.just(('edit_info',)),
    st.just(('wrap',)),
    st.tuples(st.just('unholdable_value'),
              st.sampled_from(['positions', 'momenta']), atom_index,
              st.sampled_from([np.nan, np.inf, -np.inf])),
    st.just(('non_finite_cell',)),
]
ACTIONS = {
    'argon': st.one_of(
        *common_actions,
        st.tuples(st.just('calc_set'), st.sampled_from(['epsilon', 'sigma']))),
    'copper': st.one_of(*common_actions, st.just(('strain_cell',))),
}


def action_sequences(system):
    """Rounds of a run of 1-8 steps and then one action, flattened.

    Runs come first in every round so that actions meet states away from
    the anchor, where a silent miss would show on the way back.
    """
    rounds = st.lists(st.tuples(st.integers(1, 8), ACTIONS[system]),
                      min_size=1, max_size=8)
    return rounds.map(lambda drawn: [step for steps, action in drawn
                                     for step in (('run', steps), action)])


# The quick tier draws 25 sequences on argon; the long tier 80 more there,
# and 40 on copper (EMT's force calls cost more).
@pytest.mark.parametrize('system, examples', [
    ('argon', 25), pytest.param('argon', 80, marks=SLOW),
    pytest.param('copper', 40, marks=SLOW)])
def test_any_sequence_of_actions_runs_back_to_the_last_anchor(system,
                                                              examples):
    @settings(max_examples=examples, deadline=None, derandomize=True,
              database=None, suppress_health_check=[HealthCheck.too_slow])
    @given(data=st.data(), seed=st.integers(0, 3))
    def sequence(data, seed):
        example = Example(system, seed)
        actions = data.draw(action_sequences(system), label='actions')
        for action in actions:
            example.apply(action)
        example.back_to_anchor()

    sequence()
