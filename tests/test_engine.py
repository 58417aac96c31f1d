"""The engine on its own: dynamics declared as exact variables and shears,
with no ASE in sight.  Exactness over a matrix of plans and compositions."""

import json
import math

import numpy as np
import pytest

from ase_reversible.core.codec import round_odd
from ase_reversible.core.compositions import COMPOSITIONS
from ase_reversible.core.engine import Engine
from ase_reversible.core.plans import SubStep
from ase_reversible.core.record import read_record, write_record
from ase_reversible.core.variables import ExactVariable
from ase_reversible.errors import QuantumRangeError


class Shear(SubStep):
    """``target += round_odd(c h f(*sources) / q_target)``: the smallest
    sub-step there is."""

    def __init__(self, target, sources, f):
        self.target, self.sources, self.f = target, sources, f
        self.calls = 0

    def prepare(self, ch):
        return ch / self.target.quantum

    def apply(self, scale):
        self.calls += 1
        y = scale * self.f(*(s.floats for s in self.sources))
        self.target.add_integers(round_odd(y))


def oscillator(n=5, seed=0):
    """Coupled anharmonic oscillators, plus a third variable ``z`` that
    feels the momenta and pushes back on them (an extended system)."""
    rng = np.random.default_rng(seed)
    q = 2.0**-40
    x = ExactVariable('x', rng.integers(-2**40, 2**40, n), q)
    p = ExactVariable('p', rng.integers(-2**40, 2**40, n), q)
    z = ExactVariable('z', np.zeros(1, np.int64), q)
    drift = Shear(x, (p,), lambda p: p)
    kick = Shear(p, (x, z), lambda x, z: -x - 0.1 * x**3
                 - 0.5 * (np.roll(x, 1) - x) - z[0] * 0.01)
    thermo = Shear(z, (p,), lambda p: np.array([np.mean(p**2) - 1.0]))
    return {'x': x, 'p': p, 'z': z}, drift, kick, thermo


def steps(engine, n):
    for _ in range(n):
        engine.step()


def oscillator_engine(scheme, composition, dt):
    variables, drift, kick, thermo = oscillator()
    return variables, Engine(variables, SCHEMES[scheme](drift, kick, thermo),
                             COMPOSITIONS[composition], dt)


SCHEMES = {
    'kdk': lambda d, k, t: ((k, 0.5), (d, 1.0), (k, 0.5)),
    'dkd': lambda d, k, t: ((d, 0.5), (k, 1.0), (d, 0.5)),
    'extended': lambda d, k, t: ((t, 0.5), (k, 0.5), (d, 1.0), (k, 0.5),
                                 (t, 0.5)),
}


@pytest.mark.parametrize('composition', list(COMPOSITIONS))
@pytest.mark.parametrize('scheme', list(SCHEMES))
def test_any_declared_plan_runs_back_bit_for_bit(scheme, composition):
    variables, engine = oscillator_engine(scheme, composition, 0.05)
    start = engine.snapshot()
    steps(engine, 60)
    assert not np.array_equal(engine.snapshot()['x'], start['x'])
    engine.reverse()
    steps(engine, 60)
    for name, counts in start.items():
        assert np.array_equal(engine.variables[name].ints, counts)
    assert engine.step_index == 0 and engine.elapsed() == 0.0


def test_neighbouring_substeps_are_merged_and_the_plan_is_a_palindrome():
    variables, drift, kick, thermo = oscillator()
    engine = Engine(variables, SCHEMES['kdk'](drift, kick, thermo),
                    COMPOSITIONS['suzuki-5'], 0.05)
    kinds = [s for s, _ in engine.plan]
    # 5 stages of k d k share their inner kicks: 6 kicks and 5 drifts.
    assert kinds.count(kick) == 6 and kinds.count(drift) == 5
    assert [c for _, c in engine.plan] == [c for _, c in engine.plan[::-1]]
    engine.step()
    assert kick.calls == 6


class Failing(SubStep):
    """Raises on its n-th call, after the sub-steps before it ran."""

    def __init__(self, fail_at):
        self.fail_at, self.calls = fail_at, 0

    def apply(self, ch):
        self.calls += 1
        if self.calls == self.fail_at:
            raise RuntimeError('calculator crashed')


class Buffer:
    """Side state: a stack that a step pushes to and rollback restores."""

    def __init__(self):
        self.items, self._saved = [], 0

    def checkpoint(self):
        self._saved = len(self.items)

    def rollback(self):
        del self.items[self._saved:]


def test_a_failed_step_rolls_back_every_variable_and_the_side_state():
    variables, drift, kick, thermo = oscillator()
    failing = Failing(fail_at=2)
    buffer = Buffer()

    class Push(SubStep):
        def apply(self, ch):
            buffer.items.append(ch)

    push = Push()
    engine = Engine(variables, ((kick, 0.5), (push, 0.5), (drift, 1.0),
                                (failing, 1.0), (drift, 1.0), (push, 0.5),
                                (kick, 0.5)),
                    COMPOSITIONS['verlet'], 0.05, side=(buffer,))
    engine.step()  # the first call of `failing` passes
    before, items = engine.snapshot(), list(buffer.items)
    with pytest.raises(RuntimeError, match='crashed'):
        engine.step()
    for name, counts in before.items():
        assert np.array_equal(engine.variables[name].ints, counts)
    assert buffer.items == items and engine.step_index == 1


def test_an_out_of_range_update_is_refused_and_leaves_the_value():
    x = ExactVariable('x', np.array([2**52]), 1.0)
    p = ExactVariable('p', np.array([2**52]), 1.0)
    engine = Engine({'x': x, 'p': p}, ((Shear(x, (p,), lambda p: p), 1.0),),
                    COMPOSITIONS['verlet'], 2.0)
    with pytest.raises(QuantumRangeError):
        engine.step()
    assert x.ints[0] == 2**52


def test_a_new_step_size_keeps_the_clock_exact_and_moves_the_anchor():
    variables, engine = oscillator_engine('kdk', 'verlet', 0.1)
    steps(engine, 7)
    assert engine.set_dt(0.03) == 7  # seven steps taken since the anchor
    assert np.array_equal(engine.anchor['x'], variables['x'].ints)
    steps(engine, 5)
    assert engine.elapsed() == math.fsum([7 * 0.1, 5 * 0.03])
    engine.reverse()
    steps(engine, 5)
    engine.set_dt(-0.1)
    steps(engine, 7)
    assert engine.elapsed() == 0.0


def test_the_restart_record_keeps_every_variable():
    variables, engine = oscillator_engine('extended', 'verlet', 0.05)
    steps(engine, 30)
    info = {}
    quanta = {name: v.quantum for name, v in variables.items()}
    write_record(info, quanta, engine.elapsed(),
                 hidden={'z': variables['z'].ints})
    json_info = json.loads(json.dumps(info))  # as a trajectory stores it
    record = read_record(json_info, names=('x', 'p', 'z'), hidden=('z',))
    assert record['time'] == engine.elapsed()
    assert [record[f'{n}_quantum'] for n in 'xpz'] == [2.0**-40] * 3
    assert np.array_equal(record['z'], variables['z'].ints)
    assert record['z'].dtype == np.int64
    assert read_record({'reversible': {**info['reversible'], 'z': 'x'}},
                       names=('x',), hidden=('z',)) is None
