"""The library's results, bit for bit, as they were before the engine rewrite.

Each case runs a fixed system for a fixed number of steps and reduces the
exact result -- the int64 positions and momenta, the quanta and the clock,
or the float64 bytes of a ``backpropagate`` gradient -- to a SHA-256
fingerprint.  ``fingerprints.json`` holds the fingerprints recorded by
``python tests/test_fingerprints.py --record`` on commit 7a225b0, the last
one before the integrator was rebuilt on the engine in ``ase_reversible.core``.
The rebuild must not change one bit of any of them; neither may later work
that does not mean to change the dynamics (if a change is meant to, record
again and say why in the commit).

The systems are built here, not by shared test helpers, so that a change
to those helpers cannot move the fingerprints.
"""

import hashlib
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones as AseLJ
from ase.cluster import Icosahedron
from ase.constraints import FixAtoms
from ase.io import read
from ase.md.velocitydistribution import MaxwellBoltzmannDistribution

from ase_reversible import (LennardJones, PendulumChain, ReversibleVerlet,
                            SoftenedGravity)
from ase_reversible.purity import DEFAULT_FORCE_NOISE

RECORD = Path(__file__).with_name('fingerprints.json')
DT = 5 * units.fs


def _momenta(atoms, temperature_K, seed):
    with warnings.catch_warnings():  # deprecated in ASE 3.29, kept in all
        warnings.simplefilter('ignore', DeprecationWarning)
        MaxwellBoltzmannDistribution(atoms, temperature_K=temperature_K,
                                     rng=np.random.default_rng(seed))
    return atoms


def _argon(shells, temperature_K=100, seed=1):
    atoms = Icosahedron('Ar', shells, latticeconstant=5.26)
    atoms.center(vacuum=10.0)
    return _momenta(atoms, temperature_K, seed)


def _copper(size=(2, 2, 2), temperature_K=600, seed=2):
    atoms = bulk('Cu', cubic=True) * size
    atoms.rattle(0.05, seed=seed)
    return _momenta(atoms, temperature_K, seed)


def _ase_lj():
    return AseLJ(sigma=3.4, epsilon=0.0104, rc=8.5)


def _own_lj():
    return LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)


def _asap3():
    return pytest.importorskip(
        'asap3', reason='asap3 is not installed (it is in the test extra)')


def _digest(*parts):
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
    return h.hexdigest()


def _state_digest(dyn):
    state = dyn.state
    assert state.ix_nc.dtype == np.int64 and state.ip_nc.dtype == np.int64
    return _digest(state.ix_nc, state.ip_nc, dyn.grid.position_quantum,
                   dyn.grid.momentum_quantum, float(dyn.get_time()))


def _run(atoms, calc, steps, **kwargs):
    atoms.calc = calc
    dyn = ReversibleVerlet(atoms, kwargs.pop('timestep', DT), **kwargs)
    dyn.run(steps)
    return _state_digest(dyn)


def lj13_velocity_order2():
    return _run(_argon(2), _ase_lj(), 300)


def lj55_position_order4():
    return _run(_argon(3), _ase_lj(), 30, scheme='position', order=4)


def lj13_velocity_order6():
    return _run(_argon(2), _ase_lj(), 20, order=6)


def lj13_position_triple_jump_backwards():
    return _run(_argon(2), _ase_lj(), 60, scheme='position', order=4,
                composition='triple-jump', timestep=-DT)


def cu32_emt_periodic_fixatoms_position():
    atoms = _copper()
    atoms.set_constraint(FixAtoms(indices=[0, 1, 2, 3]))
    return _run(atoms, EMT(), 100, scheme='position')


def cu32_emt_periodic_velocity_order4():
    return _run(_copper(), EMT(), 12, order=4)


# Recorded when 'auto' gave asap3 the default bound; it now measures one
# per system (a finer momentum quantum), so the bound is given here.
def cu108_asap_emt_periodic_velocity():
    asap3 = _asap3()
    return _run(_copper((3, 3, 3)), asap3.EMT(), 200,
                force_noise=DEFAULT_FORCE_NOISE)


def ar55_asap_lj_free_position_order4():
    asap3 = _asap3()
    calc = asap3.LennardJones([18], [0.0104], [3.4], rCut=8.5, modified=True)
    return _run(_argon(3), calc, 30, scheme='position', order=4,
                force_noise=DEFAULT_FORCE_NOISE)


def ar55_own_lj_velocity_given_quanta():
    return _run(_argon(3), _own_lj(), 150, position_quantum=2.0**-36,
                momentum_quantum=2.0**-42)


def ring_gravity_velocity():
    from ase_reversible.calculators import make_ring
    atoms = make_ring(24, spin=0.5)
    return _run(atoms, SoftenedGravity(), 200, timestep=0.05)


def chain_pendulum_position_order4():
    from ase_reversible.calculators import make_chain
    atoms = make_chain(5)
    return _run(atoms, PendulumChain(), 200, scheme='position', order=4,
                timestep=0.01)


def reversal_midway():
    atoms = _argon(2)
    atoms.calc = _ase_lj()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(80)
    dyn.reverse()
    dyn.run(30)
    return _state_digest(dyn)


def time_step_change_midway():
    atoms = _argon(2)
    atoms.calc = _ase_lj()
    dyn = ReversibleVerlet(atoms, DT, scheme='position')
    dyn.run(40)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        dyn.dt = 2 * units.fs
    dyn.run(40)
    return _state_digest(dyn)


def restart_from_frame(tmp_path):
    traj = tmp_path / 'md.traj'
    atoms = _argon(3)
    atoms.calc = _ase_lj()
    ReversibleVerlet(atoms, DT, trajectory=str(traj), loginterval=10).run(60)
    resumed = read(traj, 2)
    resumed.calc = _ase_lj()
    dyn = ReversibleVerlet(resumed, DT)
    dyn.run(30)
    return _state_digest(dyn)


def backpropagate_analytic():
    atoms = _argon(3)
    atoms.calc = _own_lj()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(40)
    g = dyn.backpropagate(40, np.ones((len(atoms), 3)),
                          np.full((len(atoms), 3), 0.5),
                          parameters=('epsilon', 'sigma'))
    return _digest(g.positions, g.momenta, sorted(g.parameters.items()),
                   g.hessian_vector_products) + ' ' + _state_digest(dyn)


def backpropagate_finite_difference_position():
    atoms = _argon(2)
    atoms.calc = _ase_lj()
    dyn = ReversibleVerlet(atoms, DT, scheme='position')
    dyn.run(25)
    g = dyn.backpropagate(25, atoms.positions.copy())
    return _digest(g.positions, g.momenta, g.hessian_vector_products) + \
        ' ' + _state_digest(dyn)


CASES = [lj13_velocity_order2, lj55_position_order4, lj13_velocity_order6,
         lj13_position_triple_jump_backwards,
         cu32_emt_periodic_fixatoms_position,
         cu32_emt_periodic_velocity_order4, cu108_asap_emt_periodic_velocity,
         ar55_asap_lj_free_position_order4, ar55_own_lj_velocity_given_quanta,
         ring_gravity_velocity, chain_pendulum_position_order4,
         reversal_midway, time_step_change_midway, restart_from_frame,
         backpropagate_analytic, backpropagate_finite_difference_position]


def _compute(case, tmp_path):
    if 'tmp_path' in case.__code__.co_varnames[:case.__code__.co_argcount]:
        return case(tmp_path)
    return case()


@pytest.mark.parametrize('case', CASES, ids=[c.__name__ for c in CASES])
def test_fingerprint_unchanged(case, tmp_path):
    expected = json.loads(RECORD.read_text())[case.__name__]
    assert _compute(case, tmp_path) == expected


if __name__ == '__main__' and sys.argv[1:] == ['--record']:
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        RECORD.write_text(json.dumps(
            {c.__name__: _compute(c, Path(tmp)) for c in CASES},
            indent=1) + '\n')
    print(f'wrote {RECORD}')
