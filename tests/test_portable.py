"""A run written on one machine goes back to its start on another.

The package's calculators and the integrators' own float work use only
correctly rounded operations in a fixed order
(:mod:`ase_reversible.core.portable`), so they give the same bits on every
CPU.  Each test crosses the emulated machines of ``tests/machines.py``: one
leg runs forward on this CPU as it is, writing a trajectory (and, for
Langevin, the buffer file); the next leg, on a machine with numpy's SIMD
dispatch narrowed and another OpenBLAS core type, continues from the last
frame, reverses and runs back.  The state it ends in must be the first
frame's, compared with ``np.array_equal`` on every exact variable.

The momentum quantum is set fine (2**-50 or 2**-48) so that a last-bit
change of a force flips the rounding of a kick often, and a kernel that
is not portable is caught within a few steps.  Measured with the code
before :mod:`ase_reversible.core.portable` (numpy powers and BLAS in the
Lennard-Jones, Nosé and adjoint kernels), forward on this CPU, back on
``sse4``: Ar55 missed its start under Verlet order 4 (12 steps), Langevin
(12) and Nosé (40); periodic argon under Verlet order 2 (40), order 4
(20) and Nosé (12).  Gravity and the chain came back (their kernels were
already products, ``sqrt`` and sums), as did Ar55 under order-2 Verlet
for 40 steps: a flip is likely, not certain, in a short run.  The
``backpropagate`` parameter gradients differed between two machines in
all four gradient cases below (a BLAS ``vdot``).
"""

import textwrap

import numpy as np
import pytest

from machines import emulation_works, run_leg

#: Builds the systems and dynamics in every leg.  ``SYSTEM`` and
#: ``DYNAMICS`` are set before it runs.
SETUP = textwrap.dedent('''
    import warnings
    import numpy as np
    from ase import units
    from ase.build import bulk
    from ase.cluster import Icosahedron
    from ase.io import read
    from ase.md.velocitydistribution import (MaxwellBoltzmannDistribution,
                                             Stationary)
    from ase_reversible import (LennardJones, PendulumChain,
                                ReversibleLangevin, ReversibleNose,
                                ReversibleVerlet, SoftenedGravity)
    from ase_reversible.calculators import make_chain, make_ring

    warnings.simplefilter('ignore')

    def thermal(atoms, temperature_K, seed):
        MaxwellBoltzmannDistribution(atoms, temperature_K=temperature_K,
                                     rng=np.random.default_rng(seed))
        Stationary(atoms)
        return atoms

    def argon_lj():
        return LennardJones(sigma=3.4, epsilon=0.0104, rc=8.5)

    def ar55():
        atoms = Icosahedron('Ar', 3, latticeconstant=5.26)
        atoms.center(vacuum=10.0)
        return thermal(atoms, 80, 1)

    def argon_periodic():
        atoms = bulk('Ar', 'fcc', a=5.26, cubic=True) * (2, 2, 2)
        atoms.rattle(0.1, seed=3)
        return thermal(atoms, 80, 2)

    SYSTEMS = {  # builder, calculator, time step, momentum quantum
        'ar55': (ar55, argon_lj, 5 * units.fs, 2.0**-50),
        'argon_periodic': (argon_periodic, argon_lj, 5 * units.fs,
                           2.0**-50),
        'gravity': (lambda: make_ring(12, spin=0.5, jitter=0.3),
                    SoftenedGravity, 0.05, 2.0**-48),
        'chain': (lambda: make_chain(4), PendulumChain, 0.01, 2.0**-48),
    }

    def dynamics(atoms, dt, quantum, **kwargs):
        settings = dict(momentum_quantum=quantum, **kwargs)
        if DYNAMICS.startswith('verlet'):
            return ReversibleVerlet(atoms, dt, order=int(DYNAMICS[-1]),
                                    **settings)
        if DYNAMICS == 'nose':
            return ReversibleNose(atoms, dt, 100, 50 * dt, **settings)
        return ReversibleLangevin(atoms, dt, 100, 0.5 / dt / 10, seed=7,
                                  **settings)

    build, calc, dt, quantum = SYSTEMS[SYSTEM]
''')

FORWARD = textwrap.dedent('''
    atoms = build()
    atoms.calc = calc()
    dyn = dynamics(atoms, dt, quantum, trajectory='run.traj',
                   loginterval=STEPS)
    np.savez('start.npz', elapsed=dyn.get_time(), **dyn.counts)
    dyn.run(STEPS)
    if DYNAMICS == 'langevin':
        dyn.write_buffer('buffer.npz')
''')

BACK = textwrap.dedent('''
    atoms = read('run.traj', -1)
    atoms.calc = calc()
    extra = {'buffer': 'buffer.npz'} if DYNAMICS == 'langevin' else {}
    dyn = dynamics(atoms, dt, None, **extra)
    dyn.reverse()
    dyn.run(STEPS)
    np.savez('end.npz', elapsed=dyn.get_time(), **dyn.counts)
''')


def _script(system, dynamics, steps, body):
    return (f'SYSTEM, DYNAMICS, STEPS = {system!r}, {dynamics!r}, '
            f'{steps}\n' + SETUP + body)


def _npz(path):
    with np.load(path) as f:
        return {key: f[key] for key in f.files}


def there_and_back(tmp_path, system, dynamics, steps, out='native',
                   back='sse4'):
    """Forward on ``out``, back on ``back``: (start, end) arrays by name."""
    run_leg(out, _script(system, dynamics, steps, FORWARD), tmp_path)
    run_leg(back, _script(system, dynamics, steps, BACK), tmp_path)
    return _npz(tmp_path / 'start.npz'), _npz(tmp_path / 'end.npz')


def assert_back_at_start(start, end):
    """Every exact variable's counts, and the time, bit for bit.  Nosé's
    clock (``'time'``) counts from zero in each run, from the record's
    time on: it is compared as the time it makes (``'elapsed'``)."""
    assert sorted(end) == sorted(start)
    for name in start:
        if name != 'time':
            assert np.array_equal(start[name], end[name]), name


#: One quick case; the long tier runs every system under every dynamics.
FAST = [('ar55', 'verlet4', 12)]
SLOW = [(system, dynamics, steps)
        for system in ('ar55', 'argon_periodic', 'gravity', 'chain')
        for dynamics, steps in (('verlet2', 40), ('verlet4', 20),
                                ('nose', 40), ('langevin', 40))
        if (system, dynamics) not in {(s, d) for s, d, _ in FAST}]


@pytest.fixture(scope='module')
def machines_differ(tmp_path_factory):
    if not emulation_works(tmp_path_factory.mktemp('emulation')):
        pytest.skip('the emulated machines compute the same bits here')


@pytest.mark.parametrize('system, dynamics, steps', FAST,
                         ids=[f'{s}-{d}' for s, d, _ in FAST])
def test_out_on_one_machine_back_on_another(tmp_path, machines_differ,
                                            system, dynamics, steps):
    assert_back_at_start(*there_and_back(tmp_path, system, dynamics, steps))


@pytest.mark.slow
@pytest.mark.parametrize('system, dynamics, steps', SLOW,
                         ids=[f'{s}-{d}' for s, d, _ in SLOW])
def test_every_system_and_dynamics_crosses_machines(tmp_path,
                                                    machines_differ, system,
                                                    dynamics, steps):
    back = 'avx2' if dynamics == 'verlet2' else 'sse4'
    assert_back_at_start(*there_and_back(tmp_path, system, dynamics, steps,
                                         back=back))


GRADIENTS = textwrap.dedent('''
    atoms = build()
    atoms.calc = calc()
    dyn = dynamics(atoms, dt, quantum)
    dyn.run(STEPS)
    n = len(atoms)
    g = dyn.backpropagate(STEPS, np.ones((n, 3)), np.full((n, 3), 0.5),
                          parameters=('epsilon', 'sigma'))
    np.savez(OUT, positions=g.positions,
             momenta=g.momenta,
             parameters=[g.parameters['epsilon'], g.parameters['sigma']],
             products=g.hessian_vector_products, **dyn.counts)
''')


def gradients_on_two_machines(tmp_path, system, dynamics, steps):
    legs = {}
    for machine in ('native', 'sse4'):
        script = _script(system, dynamics, steps,
                         f'OUT = {machine + ".npz"!r}\n' + GRADIENTS)
        run_leg(machine, script, tmp_path)
        legs[machine] = _npz(tmp_path / f'{machine}.npz')
    assert legs['native']['products'] > 0
    for name, value in legs['native'].items():
        assert value.tobytes() == legs['sse4'][name].tobytes(), name


def test_gradients_are_the_same_bytes_on_two_machines(tmp_path,
                                                      machines_differ):
    # Analytic Hessian-vector products and parameter gradients of the
    # package's Lennard-Jones, order 4 so that the composition counts too.
    gradients_on_two_machines(tmp_path, 'ar55', 'verlet4', 6)


@pytest.mark.slow
@pytest.mark.parametrize('system, dynamics', [
    ('ar55', 'nose'), ('ar55', 'langevin'), ('argon_periodic', 'verlet2')])
def test_thermostat_gradients_are_the_same_bytes_on_two_machines(
        tmp_path, machines_differ, system, dynamics):
    gradients_on_two_machines(tmp_path, system, dynamics, 20)


def test_the_software_exponential_is_correctly_rounded():
    # The friction ratio of ReversibleLangevin comes from it: checked
    # against 60-digit decimal arithmetic, not against a libm (which on the
    # development machine missed the correctly rounded value in 78 of
    # 100,000 such arguments).
    import decimal

    from ase_reversible.core import portable
    wide = decimal.Context(prec=60)
    rng = np.random.default_rng(5)
    for x in -rng.uniform(1e-6, 11.0, 1000):
        assert portable.exp(x) == float(wide.exp(decimal.Decimal(x)))
    for y in rng.uniform(2.0**-16, 1.0, 1000):
        assert portable.log(y) == float(wide.ln(decimal.Decimal(y)))
