"""Losses along a run: one retrace gathers a loss on many states
(``backpropagate(..., loss=, every=, window=)``).

Checked against the segment-by-segment retraces the library had before
(which add each state's gradient between calls), against finite
differences of whole runs, and for the truncated objective against one
retrace per window.  Exactness of the state after each retrace with
``np.array_equal``.
"""

import numpy as np
import pytest
from ase import units
from ase.md.velocitydistribution import Stationary

from ase_reversible import (LennardJones, ReversibleLangevin,
                            ReversibleNose, ReversibleVerlet)

from conftest import AR_EPSILON, AR_SIGMA, DT
from exactness import assert_runs_back, assert_same_state, snapshot
from test_adjoint import FINE, argon

STEPS, EVERY = 60, 10


class SampledLinearLoss:
    """L = sum over sampled states k of <a_k, x_k> + <b_k, p_k>: each
    state's own gradients are (a_k, b_k), drawn at random per state."""

    def __init__(self, n, steps, every, momenta=True, seed=7):
        rng = np.random.default_rng(seed)
        self.ks = list(range(0, steps + 1, every))
        self.a = {k: rng.normal(size=(n, 3)) for k in self.ks}
        self.b = {k: rng.normal(size=(n, 3)) if momenta else None
                  for k in self.ks}
        self.seen = []

    def __call__(self, atoms, k):
        self.seen.append(k)
        return self.a[k], self.b[k]

    def value(self, states):
        """L from ``{k: (positions, momenta)}``."""
        total = 0.0
        for k in self.ks:
            x_nc, p_nc = states[k]
            total += np.vdot(self.a[k], x_nc)
            if self.b[k] is not None:
                total += np.vdot(self.b[k], p_nc)
        return total


def by_segments(dyn, loss, steps, every, **kwargs):
    """The reference: one retrace per segment between sampled states, each
    state's gradient added between calls (and the thermostat's cotangents
    carried)."""
    k = steps
    zero = np.zeros((len(dyn.atoms), 3))
    g = None
    parameters = {}
    while True:
        a_nc = loss.a[k]
        b_nc = loss.b[k] if loss.b[k] is not None else zero
        if g is not None:
            a_nc, b_nc = g.positions + a_nc, g.momenta + b_nc
        back = min(every, k)
        g = dyn.backpropagate(back, a_nc, b_nc, carry=g, **kwargs)
        for name, value in g.parameters.items():
            parameters[name] = parameters.get(name, 0.0) + value
        k -= back
        if k == 0:
            break
    b_nc = loss.b[0] if loss.b[0] is not None else zero
    return (g.positions + loss.a[0], g.momenta + b_nc), parameters


def relative(estimate, reference):
    estimate, reference = np.asarray(estimate), np.asarray(reference)
    return np.abs(estimate - reference).max() / np.abs(reference).max()


DYNAMICS = {
    'verlet': lambda atoms: ReversibleVerlet(atoms, DT, energy_check=0,
                                             **FINE),
    'langevin': lambda atoms: ReversibleLangevin(
        atoms, DT, temperature_K=80, friction=0.01 / units.fs, seed=3,
        **FINE),
    'nose': lambda atoms: ReversibleNose(Stationary(atoms) or atoms, DT, 80,
                                         50 * units.fs, energy_check=0,
                                         **FINE),
}


@pytest.mark.parametrize('dynamics', sorted(DYNAMICS))
def test_one_retrace_equals_the_retrace_by_segments(dynamics):
    names = ('epsilon', 'sigma')
    atoms = argon(2, 60)
    dyn = DYNAMICS[dynamics](atoms)
    loss = SampledLinearLoss(len(atoms), STEPS, EVERY)
    start = snapshot(atoms)
    dyn.run(STEPS)
    end = snapshot(atoms)
    g = dyn.backpropagate(STEPS, loss=loss, every=EVERY, parameters=names)
    assert_same_state(atoms, start)
    assert loss.seen == loss.ks[::-1]
    dyn.run(STEPS)
    assert_same_state(atoms, end)
    reference, parameters = by_segments(dyn, loss, STEPS, EVERY,
                                        parameters=names)
    assert_same_state(atoms, start)
    # The same sums, associated otherwise where kicks are merged.
    assert relative(g.positions, reference[0]) < 1e-12
    assert relative(g.momenta, reference[1]) < 1e-12
    for name in names:
        assert relative(g.parameters[name], parameters[name]) < 1e-12


@pytest.mark.parametrize('momenta', [False, True])
def test_a_loss_on_positions_keeps_one_product_per_step(momenta):
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    loss = SampledLinearLoss(len(atoms), STEPS, EVERY, momenta=momenta)
    dyn.run(STEPS)
    g = dyn.backpropagate(STEPS, loss=loss, every=EVERY)
    # A momentum gradient at an inner sampled state must not reach the
    # kick taken just after it: the kicks there are not merged.  Without
    # one, the last kick meets a zero momentum cotangent and costs nothing.
    inner = sum(1 for k in loss.ks if 0 < k < STEPS)
    assert g.products == (STEPS + 1 + inner if momenta else STEPS)


def test_parameter_gradients_of_a_time_average_match_whole_runs():
    """d/d(epsilon, sigma) of a loss on seven states of an Ar13 run,
    against central differences of whole ReversibleVerlet runs (fine
    quanta: rounding is noise far below the difference)."""
    names = ('epsilon', 'sigma')
    atoms = argon(2, 60)
    loss = SampledLinearLoss(len(atoms), STEPS, EVERY, momenta=True)

    def whole_run(**calc_set):
        atoms = argon(2, 60)
        atoms.calc.set(**calc_set)
        dyn = ReversibleVerlet(atoms, DT, energy_check=0, **FINE)
        states = {0: snapshot(atoms)}
        for k in range(EVERY, STEPS + 1, EVERY):
            dyn.run(EVERY)
            states[k] = snapshot(atoms)
        return loss.value(states)

    dyn = ReversibleVerlet(atoms, DT, energy_check=0, **FINE)
    dyn.run(STEPS)
    g = dyn.backpropagate(STEPS, loss=loss, every=EVERY, parameters=names)
    for name in names:
        value = atoms.calc.parameters[name]
        h = 1e-6 * value
        fd = (whole_run(**{name: value + h})
              - whole_run(**{name: value - h})) / (2 * h)
        assert relative(g.parameters[name], fd) < 1e-6, name


@pytest.mark.parametrize('window', [3, EVERY])
def test_windows_truncate_each_gradient_and_skip_the_steps_between(window):
    names = ('epsilon', 'sigma')
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT, energy_check=0, **FINE)
    loss = SampledLinearLoss(len(atoms), STEPS, EVERY)
    start = snapshot(atoms)
    dyn.run(STEPS)
    g = dyn.backpropagate(STEPS, loss=loss, every=EVERY, window=window,
                          parameters=names)
    assert_same_state(atoms, start)
    # One product per step inside a window (window + 1 for its steps), none
    # between windows.
    windows = sum(1 for k in loss.ks if k > 0)
    assert g.products == windows * (window + 1)

    # The reference: for each sampled state, a retrace of its window alone.
    expected = {name: 0.0 for name in names}
    reaching_start = np.zeros((len(atoms), 3))
    for k in loss.ks:
        if k == 0:
            continue
        dyn.run(k)
        back = min(window, k)
        gk = dyn.backpropagate(back, loss.a[k], loss.b[k], parameters=names)
        for name in names:
            expected[name] += gk.parameters[name]
        if k - back == 0:
            reaching_start += gk.positions
        dyn.backpropagate(k - back, np.zeros((len(atoms), 3)))
        assert_same_state(atoms, start)
    for name in names:
        assert relative(g.parameters[name], expected[name]) < 1e-12
    # The state-0 gradient: its own loss plus the windows that reach it.
    np.testing.assert_allclose(g.positions, reaching_start + loss.a[0],
                               rtol=1e-12, atol=1e-12)


def test_a_windowed_loss_runs_back_exactly_and_forward_again():
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    loss = SampledLinearLoss(len(atoms), STEPS, EVERY)
    dyn.run(STEPS)
    end = snapshot(atoms)
    dyn.backpropagate(STEPS, loss=loss, every=EVERY, window=4)
    dyn.run(STEPS)
    assert_same_state(atoms, end)
    assert_runs_back(dyn, 20)


def test_zero_steps_calls_the_loss_once():
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    loss = SampledLinearLoss(len(atoms), 0, 1)
    g = dyn.backpropagate(0, loss=loss)
    assert loss.seen == [0]
    assert np.array_equal(g.positions, loss.a[0])
    assert np.array_equal(g.momenta, loss.b[0])
    assert g.products == 0


@pytest.mark.parametrize('kwargs, error, match', [
    ({'loss': lambda atoms, k: None, 'every': 5, 'window': 6}, ValueError,
     'overlap'),
    ({'loss': 'rdf'}, TypeError, 'callable'),
    ({'loss': lambda atoms, k: None, 'every': 0}, ValueError, 'every'),
    ({'loss': lambda atoms, k: None, 'window': 2.5}, ValueError, 'window'),
    ({}, ValueError, 'Nothing to differentiate'),
])
def test_bad_schedules_are_refused_before_anything_moves(kwargs, error,
                                                         match):
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(10)
    end = snapshot(atoms)
    with pytest.raises(error, match=match):
        dyn.backpropagate(10, **kwargs)
    assert_same_state(atoms, end)


def test_a_loss_that_returns_a_wrong_shape_stops_the_retrace_cleanly():
    atoms = argon(2, 60)
    dyn = ReversibleVerlet(atoms, DT)
    start = snapshot(atoms)
    dyn.run(10)

    def loss(atoms, k):
        return (np.zeros((len(atoms), 3)) if k > 4
                else np.zeros((len(atoms), 2))), None

    with pytest.raises(ValueError, match=r'k=4.*shape'):
        dyn.backpropagate(10, loss=loss, every=2)
    assert dyn.dt > 0
    # Stopped at state 4, on the forward path: four more steps back lead
    # to the start.
    dyn.backpropagate(4, np.zeros((len(atoms), 3)))
    assert_same_state(atoms, start)


def test_lennard_jones_parameter_values_are_the_constructor_arguments():
    calc = LennardJones(epsilon=AR_EPSILON, sigma=AR_SIGMA)
    assert calc.parameter_values() == {'epsilon': AR_EPSILON,
                                       'sigma': AR_SIGMA}
