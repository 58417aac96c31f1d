"""The library's results, bit for bit, on every machine.

Each case runs a fixed system for a fixed number of steps and reduces the
exact result -- every exact variable's int64 counts, the quanta and the
clock, or the float64 bytes of a ``backpropagate`` gradient -- to a
SHA-256 fingerprint.  ``fingerprints.json`` holds the fingerprints
recorded by ``python tests/test_fingerprints.py --record``.  Work that does
not mean to change the dynamics must not change one bit of any of them
(if a change is meant to, record again and say why in the commit).

Only computations that give the same bits on every CPU are fingerprinted:
the package's own calculators, whose kernels and the integrators' float
work are correctly rounded operations in a fixed order
(:mod:`ase_reversible.core.portable`).  Each fingerprint is checked here
and, in subprocesses, on the emulated machines of ``tests/machines.py``
(numpy's SIMD dispatch narrowed, another OpenBLAS core type).  The
integrator's paths that earlier cases took with other calculators are
taken here with the package's Lennard-Jones: periodic images with
FixAtoms and order 4 (were ASE's EMT on copper), guarded rounding (was
asap3), finite-difference Hessian-vector products (were ASE's
Lennard-Jones).  Those calculators are not fingerprinted: ASE's EMT and
Lennard-Jones call numpy's ``exp`` and powers, whose last bits differ
between CPUs (the two EMT fingerprints recorded on one machine changed
on an Intel Xeon with AVX-512), and asap3 is compiled code calling the C
library's ``exp``, which the emulated machines cannot vary: their bits
would be one CPU's, not the library's.

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
from ase.cluster import Icosahedron
from ase.constraints import FixAtoms
from ase.io import read
from ase.md.velocitydistribution import (MaxwellBoltzmannDistribution,
                                         Stationary)

from ase_reversible import (LennardJones, PendulumChain, ReversibleLangevin,
                            ReversibleNose, ReversibleVerlet,
                            SoftenedGravity)
from ase_reversible.purity import DEFAULT_FORCE_NOISE

from machines import run_leg

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


def _argon_crystal(temperature_K=60, seed=2):
    atoms = bulk('Ar', 'fcc', a=5.26, cubic=True) * (2, 2, 2)
    atoms.rattle(0.05, seed=seed)
    return _momenta(atoms, temperature_K, seed)


def _own_lj():
    return LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)


def _digest(*parts):
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
    return h.hexdigest()


def _state_digest(dyn):
    counts = dyn.counts
    assert all(c.dtype == np.int64 for c in counts.values())
    return _digest(*(counts[name] for name in sorted(counts)), sorted(counts),
                   dyn.grid.position_quantum, dyn.grid.momentum_quantum,
                   float(dyn.get_time()))


def _run(atoms, calc, steps, dynamics=ReversibleVerlet, *args, **kwargs):
    atoms.calc = calc
    dyn = dynamics(atoms, kwargs.pop('timestep', DT), *args, **kwargs)
    dyn.run(steps)
    return _state_digest(dyn)


def lj13_velocity_order2():
    return _run(_argon(2), _own_lj(), 300)


def lj55_position_order4():
    return _run(_argon(3), _own_lj(), 30, scheme='position', order=4)


def lj13_velocity_order6():
    return _run(_argon(2), _own_lj(), 20, order=6)


def lj13_position_triple_jump_backwards():
    return _run(_argon(2), _own_lj(), 60, scheme='position', order=4,
                composition='triple-jump', timestep=-DT)


def ar32_periodic_fixatoms_position():
    atoms = _argon_crystal()
    atoms.set_constraint(FixAtoms(indices=[0, 1, 2, 3]))
    return _run(atoms, _own_lj(), 100, scheme='position')


def ar32_periodic_velocity_order4():
    return _run(_argon_crystal(), _own_lj(), 12, order=4)


def ar55_guarded_position_order4():
    return _run(_argon(3), _own_lj(), 30, scheme='position', order=4,
                force_purity='guarded', force_noise=DEFAULT_FORCE_NOISE)


def lj13_nose_order4():
    atoms = _argon(2)
    Stationary(atoms)
    return _run(atoms, _own_lj(), 100, ReversibleNose, 60, 100 * DT,
                order=4)


def lj13_langevin():
    return _run(_argon(2), _own_lj(), 100, ReversibleLangevin, 60,
                0.01 / units.fs, seed=11)


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
    atoms.calc = _own_lj()
    dyn = ReversibleVerlet(atoms, DT)
    dyn.run(80)
    dyn.reverse()
    dyn.run(30)
    return _state_digest(dyn)


def time_step_change_midway():
    atoms = _argon(2)
    atoms.calc = _own_lj()
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
    atoms.calc = _own_lj()
    ReversibleVerlet(atoms, DT, trajectory=str(traj), loginterval=10).run(60)
    resumed = read(traj, 2)
    resumed.calc = _own_lj()
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
    atoms.calc = _own_lj()
    dyn = ReversibleVerlet(atoms, DT, scheme='position')
    dyn.run(25)
    g = dyn.backpropagate(25, atoms.positions.copy(),
                          hvp='finite-difference')
    return _digest(g.positions, g.momenta, g.hessian_vector_products) + \
        ' ' + _state_digest(dyn)


CASES = [lj13_velocity_order2, lj55_position_order4, lj13_velocity_order6,
         lj13_position_triple_jump_backwards, ar32_periodic_fixatoms_position,
         ar32_periodic_velocity_order4, ar55_guarded_position_order4,
         lj13_nose_order4, lj13_langevin, ar55_own_lj_velocity_given_quanta,
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


def _on_machine(machine, names, tmp_path):
    """The fingerprints of the cases ``names`` computed on ``machine``."""
    script = ('import json, sys, tempfile\n'
              'from pathlib import Path\n'
              f'sys.path.insert(0, {str(Path(__file__).parent)!r})\n'
              'import test_fingerprints as t\n'
              'with tempfile.TemporaryDirectory() as tmp:\n'
              '    print(json.dumps({c.__name__: t._compute(c, Path(tmp))\n'
              f'                      for c in t.CASES if c.__name__ in '
              f'{list(names)!r}}}))\n')
    return json.loads(run_leg(machine, script, tmp_path))


def _expected(names):
    record = json.loads(RECORD.read_text())
    return {name: record[name] for name in names}


def test_a_fingerprint_is_the_same_on_another_machine(tmp_path):
    names = ['chain_pendulum_position_order4', 'backpropagate_analytic']
    assert _on_machine('sse4', names, tmp_path) == _expected(names)


@pytest.mark.slow
@pytest.mark.parametrize('machine', ['avx2', 'sse4'])
def test_every_fingerprint_is_the_same_on_other_machines(machine, tmp_path):
    names = [c.__name__ for c in CASES]
    assert _on_machine(machine, names, tmp_path) == _expected(names)


if __name__ == '__main__' and sys.argv[1:] == ['--record']:
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        RECORD.write_text(json.dumps(
            {c.__name__: _compute(c, Path(tmp)) for c in CASES},
            indent=1) + '\n')
    print(f'wrote {RECORD}')
