"""ReversibleBussi: exact reversal of stochastic velocity rescaling, its
buffer, its draws and its contract.

Every reversal case compares positions and momenta with np.array_equal
against the state right after the constructor, checks the run went
somewhere, and that the buffer (states, stacks, ratios) is empty again.
"""

import json
import math

import numpy as np
import pytest
from ase import units
from ase.constraints import FixAtoms, FixCartesian, FixCom, FixedLine
from ase.md.bussi import Bussi
from hypothesis import assume, example, given, settings, strategies as st

from ase_reversible import (AnchorMovedWarning, ReversibleBussi,
                            UnstableIntegrationError,
                            UnsupportedConstraintError)
from ase_reversible.core.noise import BussiDraws, portable_log, step_key
from ase_reversible.core.scaling import (N_MAX, N_MIN, RATIO_BITS,
                                         ScalingBuffer)

from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, CALCULATORS,
                      THERMOSTAT_CASES, argon_bulk, copper_bulk)
from exactness import assert_runs_back, assert_same_state, snapshot
from machines import run_leg
from thermostats import ar13, assert_buffers_empty, bussi
from tiers import SLOW, tiered

D = 1 << RATIO_BITS


# -- the buffer ---------------------------------------------------------------

counts = st.lists(st.integers(-2**52, 2**52), min_size=1, max_size=12)
ratios = st.lists(st.integers(N_MIN, N_MAX - 1)
                  | st.integers(D - 3000, D + 3000), min_size=1, max_size=40)


@settings(max_examples=150, deadline=None)
@given(counts, ratios, st.integers(0, 2**32))
# A chain whose product leaves the counts' range (found by hypothesis).
@example([4503599249092482], [37748738, 134217727], 265556934)
def test_scaling_is_undone_bit_for_bit_for_ratios_on_both_sides_of_one(
        xs, ns, seed):
    """Any sequence of ratios, below and above 1, out and back: the counts
    and the buffer are what they were; each product is within
    max(1, n / 2**20) counts of x n / 2**20 (ratios above one need the
    reserve below an empty stack)."""
    buffer = ScalingBuffer(len(xs), step_key(seed, 1.0))
    x = np.array(xs, dtype=np.int64)
    path = [x]
    for n in ns:
        if np.abs(path[-1]).max() >= 2**53:
            # The momentum variable refuses counts from 2**53 on (before
            # the buffer sees them): beyond is outside the coder's domain.
            break
        new = buffer.scale(path[-1], n)
        exact = path[-1].astype(object) * n
        assert all(-D < int(a) * D - int(e) < n
                   for a, e in zip(new, exact))
        path.append(new)
    for previous in reversed(path[:-1]):
        assert np.array_equal(buffer.unscale(path.pop()), previous)
    assert buffer.is_empty()


@settings(max_examples=60, deadline=None)
@given(counts, st.integers(N_MIN, N_MAX - 1), st.integers(0, 2**32),
       st.data())
def test_every_buffer_state_and_count_has_a_preimage(xs, n, seed, data):
    """Surjective too: from any states in [2**20, 2**36) and any counts
    whose preimage is in range (below 2**53, as every count is), undoing
    a ratio and doing it again comes back (with the injectivity above: a
    bijection on (counts, buffer) for every ratio)."""
    assume(max(abs(x) for x in xs) * D < 2**53 * n)
    size = len(xs)
    buffer = ScalingBuffer(size, step_key(seed, 1.0))
    buffer.state_k = np.array(data.draw(st.lists(
        st.integers(2**20, 2**36 - 1), min_size=size, max_size=size)),
        dtype=np.int64)
    buffer.top_k = np.array(data.draw(st.lists(
        st.integers(-3, 3), min_size=size, max_size=size)), dtype=np.int64)
    buffer._reserve(-4)
    buffer._room(4)
    state, top = buffer.state_k.copy(), buffer.top_k.copy()
    words = buffer.words_jk.copy()
    buffer._push_ratio(n)
    x = np.array(xs, dtype=np.int64)
    back = buffer.unscale(x)
    assert np.array_equal(buffer.scale(back, n), x)
    assert np.array_equal(buffer.state_k, state)
    assert np.array_equal(buffer.top_k, top)
    # The stacks' contents (rows below each pointer) are as they were.
    held = np.arange(len(words))[:, None] < top + buffer.base
    assert np.array_equal(buffer.words_jk[:len(words)][held], words[held])


def test_a_masked_coordinate_and_its_buffer_stay_put():
    buffer = ScalingBuffer(3, step_key(1, 1.0))
    x = np.array([10**12, 7, -10**12], dtype=np.int64)
    mask = np.array([True, False, True])
    out = buffer.scale(x, 3 * D // 2, mask)
    assert out[1] == 7 and buffer.state_k[1] == D and buffer.top_k[1] == 0
    assert np.array_equal(buffer.unscale(out, mask), x)
    assert buffer.is_empty()


def test_a_rolled_back_step_leaves_the_buffer_as_at_its_checkpoint():
    """The engine's rollback of a failed step: the states, pointers and
    ratio count return, and the way back still leads to the start (also
    after the failed step drew reserve rows)."""
    rng = np.random.default_rng(2)
    x0 = rng.integers(-2**40, 2**40, 30)
    buffer = ScalingBuffer(30, step_key(3, 1.0))
    x1 = buffer.scale(x0, 3 * D)        # takes reserve words
    buffer.checkpoint()
    state, top = buffer.state_k.copy(), buffer.top_k.copy()
    buffer.scale(x1, 5 * D)             # one rescaling a step
    buffer.rollback()
    assert np.array_equal(buffer.state_k, state)
    assert np.array_equal(buffer.top_k, top) and buffer.count == 1
    x2 = buffer.scale(x1, D // 3)
    assert np.array_equal(buffer.unscale(buffer.unscale(x2)), x0)
    assert buffer.is_empty()


# -- the draws ----------------------------------------------------------------

def test_the_chi_squared_draws_have_their_distribution():
    """S of 1000 steps against chi-squared with N_f - 1 degrees of freedom
    (Kolmogorov-Smirnov), R against the standard normal."""
    key = step_key(5, 1.0)
    for dof in (3, 765):
        draws = BussiDraws(dof)
        r, s = np.array([draws(key, k) for k in range(1000)]).T
        assert gamma_ks_pvalue(s, (dof - 1) / 2, 2.0) > 1e-3
        assert gamma_ks_pvalue(r * r, 0.5, 2.0) > 1e-3  # chi-squared, 1
        assert abs(np.mean(r > 0) - 0.5) < 0.04  # and symmetric


def test_the_scalar_logarithm_has_the_bits_of_the_portable_one():
    x = np.random.default_rng(0).random(20_000) * 4.0 + 1e-12
    assert np.array_equal([portable_log(float(v)) for v in x],
                          portable_log(x))


# -- exact reversal -----------------------------------------------------------

@pytest.mark.parametrize('case', tiered(list(THERMOSTAT_CASES),
                                        quick=['Ar13 ase-lj', 'Cu55 ase-emt',
                                               'Cu108 asap-emt']))
def test_round_trip_is_exact(case):
    build, calc, dt_fs, steps = THERMOSTAT_CASES[case]
    atoms = build()
    atoms.calc = CALCULATORS[calc]()
    dyn = bussi(atoms, dt_fs)
    assert_runs_back(dyn, steps)
    assert_buffers_empty(dyn)
    assert dyn.get_time() == 0.0


@pytest.mark.parametrize('start_K, target_K, seed', [
    (5, 300, 2),      # heats: ratios above 1 take reserve words
    (2000, 40, 3),    # cools: ratios below 1 push words
    (60, 60, 4)])
def test_heating_and_cooling_runs_come_back_exactly(start_K, target_K, seed):
    atoms = ar13(start_K)
    dyn = bussi(atoms, temperature_K=target_K, seed=seed, taut=20 * units.fs)
    start = snapshot(atoms)
    dyn.run(150)
    temperature = atoms.get_temperature()
    buffer = dyn.rescale_step.buffer_for(dyn.dt)
    if target_K > start_K:
        assert temperature > 10 * start_K and buffer.top_k.min() < 0
    elif target_K < start_K:
        # The coordinates' buffers grew (by about 3 bits each here).
        assert temperature < start_K / 10
        assert buffer.bits - 32 * buffer.count > len(atoms) * 3
    dyn.reverse().run(150)
    assert_same_state(atoms, start)
    assert_buffers_empty(dyn)


@SLOW
@pytest.mark.parametrize('start_K, target_K, seed', [
    (50, 900, 11), (1500, 100, 12), (600, 600, 13)])
def test_asap3_copper_heats_or_cools_and_comes_back(start_K, target_K, seed):
    atoms = copper_bulk((3, 3, 3), start_K, seed=seed)
    atoms.calc = CALCULATORS['asap-emt']()
    dyn = bussi(atoms, temperature_K=target_K, seed=seed,
                taut=50 * units.fs)
    assert_runs_back(dyn, 1000)
    assert_buffers_empty(dyn)


@pytest.mark.parametrize('constraint', ['FixAtoms', 'FixCartesian', 'FixCom'])
def test_constraints_are_kept_and_reversal_is_exact(constraint):
    atoms = ar13()
    frozen = np.zeros((len(atoms), 3), bool)
    if constraint == 'FixAtoms':
        atoms.set_constraint(FixAtoms(indices=[0, 5]))
        frozen[[0, 5]] = True
    elif constraint == 'FixCartesian':
        atoms.set_constraint(FixCartesian(3, mask=(True, False, True)))
        frozen[3, [0, 2]] = True
    else:
        atoms.set_constraint(FixCom())
    dyn = bussi(atoms)
    start = snapshot(atoms)
    dyn.run(100)
    assert not np.any(atoms.get_momenta()[frozen])
    if constraint == 'FixCom':
        assert not np.any(dyn.state.ip_nc.sum(axis=0))
    dyn.reverse().run(100)
    assert_same_state(atoms, start)
    assert_buffers_empty(dyn)


def test_degrees_of_freedom_are_ases():
    for constraint, removed in ((None, 0), (FixCom(), 3),
                                (FixAtoms(indices=[1]), 3)):
        atoms = ar13()
        if constraint is not None:
            atoms.set_constraint(constraint)
        dyn = bussi(atoms)
        assert dyn.rescale_step._draws.dof == 3 * len(atoms) - removed \
            == atoms.get_number_of_degrees_of_freedom()


# -- the contract -------------------------------------------------------------

def test_ases_usual_call_works_with_the_class_name_swapped():
    atoms = ar13()
    dyn = ReversibleBussi(atoms, 5 * units.fs, temperature_K=300,
                          taut=100 * units.fs)
    dyn.run(5)
    assert dyn.taut == 100 * units.fs and dyn.temperature_K == 300


@pytest.mark.parametrize('kwargs, error, match', [
    ({'rng': np.random.default_rng(1)}, ValueError, 'both seed=1 and rng'),
    ({'fixcm': True}, TypeError, 'FixCom'),
    ({'taut': 0.0}, ValueError, 'taut must be positive'),
    ({'taut': -5 * units.fs}, ValueError, 'taut must be positive'),
    ({'taut': 'long'}, TypeError, 'taut must be a number'),
    ({'temperature_K': -1}, ValueError, 'temperature_K must be positive'),
])
def test_bad_arguments_are_refused_before_anything_changes(kwargs, error,
                                                           match):
    atoms = ar13()
    before = snapshot(atoms)
    with pytest.raises(error, match=match):
        bussi(atoms, **kwargs)
    assert_same_state(atoms, before)


def test_zero_momenta_and_a_line_constraint_are_refused():
    atoms = ar13()
    atoms.set_momenta(np.zeros((len(atoms), 3)))
    with pytest.raises(ValueError, match='MaxwellBoltzmannDistribution'):
        bussi(atoms)
    atoms = ar13()
    atoms.set_constraint(FixedLine(0, (0, 0, 1)))
    with pytest.raises(UnsupportedConstraintError,
                       match='ReversibleBussi supports.*rescaling'):
        bussi(atoms)


def test_a_factor_out_of_range_stops_before_the_step_and_loses_nothing():
    """A target of 1e9 K from 60 K would need alpha near 1e3 in the first
    step: refused, the state as before, and the run goes on and back."""
    atoms = ar13()
    dyn = bussi(atoms)
    dyn.run(10)
    with pytest.warns(AnchorMovedWarning):
        dyn.set_temperature(1e9)
    here = snapshot(atoms)
    with pytest.raises(ValueError, match=r'factors in \[2\*\*-16'):
        dyn.run(1)
    assert_same_state(atoms, here)
    assert dyn.rescale_step.buffer_for(dyn.dt).is_empty()
    dyn.set_temperature(300)
    dyn.run(20)
    dyn.reverse().run(20)
    assert_same_state(atoms, here)


def test_gradients_match_complex_step_through_a_float_bussi_run():
    """backpropagate against complex-step differentiation of a plain float
    run written here: the same kicks and drifts, and each step's factor
    alpha(K) + (n / 2**20 - alpha(Re K)) -- the stored ratio as its
    value, the formula's slope as its derivative, with the step's own
    draws -- for the initial state and the potential's epsilon and
    sigma.  Measured relative errors 4e-13 to 4e-12; without the slope's
    term (alpha a alone) 0.22 to 5.8."""
    import cmath
    from finite_differences import (argon_lj_forces, complex_step_errors,
                                    float_kick_drift_run)
    from test_adjoint import FINE, argon, random_loss
    from ase_reversible.md.bussi import decay

    steps, dt, temperature, taut = 150, 5 * units.fs, 60.0, 20 * units.fs
    atoms = argon(2, 40, rc=30.0, ro=29.0)
    a_nc, b_nc = random_loss(atoms)
    dyn = ReversibleBussi(atoms, dt, temperature, taut, seed=2,
                          energy_check=0, **FINE)
    x0_nc, p0_nc = atoms.positions.copy(), atoms.get_momenta()
    dyn.run(steps)
    buffer = dyn.rescale_step.buffer_for(dt)
    ratios = buffer.ratios[:buffer.count] / D
    g = dyn.backpropagate(steps, a_nc, b_nc,
                          parameters=('epsilon', 'sigma'))
    assert np.array_equal(atoms.positions, x0_nc)

    m_n1 = atoms.get_masses()[:, None]
    potential, forces = argon_lj_forces()
    kT, c = units.kB * temperature, decay(dt, taut)
    draws, key = BussiDraws(3 * len(atoms)), step_key(2, dt)
    noise = [draws(key, k) for k in range(steps)]

    def alpha(two_k, r, s):
        e = (1 - c) * kT / two_k
        return cmath.sqrt(c + e * (s + r * r) + 2 * r * cmath.sqrt(c * e))

    def rescale(k, p_nc):
        two_k = np.sum(p_nc * p_nc / m_n1)
        factor = (alpha(two_k, *noise[k]) - alpha(two_k.real, *noise[k])
                  + ratios[k])
        return factor * p_nc

    def loss_imag(x_nc, p_nc):
        x_nc, p_nc = float_kick_drift_run(x_nc, p_nc, m_n1, dt, steps,
                                          forces, rescale)
        return np.vdot(a_nc, x_nc.imag) + np.vdot(b_nc, p_nc.imag)

    errors = complex_step_errors(loss_imag, x0_nc, p0_nc, g, potential)
    assert max(errors) < 1e-9, errors


def test_the_energy_watch_checks_energy_minus_heat_and_loses_nothing():
    """A tolerance below the time-step error stops the run at a check with
    the watched quantity named; the state is valid and runs back."""
    atoms = ar13()
    dyn = bussi(atoms, energy_check=5, energy_tolerance=1e-9)
    start = snapshot(atoms)
    with pytest.raises(UnstableIntegrationError,
                       match='minus the heat the thermostat added'):
        dyn.run(100)
    taken = dyn.engine.step_index
    assert 0 < taken < 100
    dyn.energy_check = 0
    dyn.reverse().run(taken)
    assert_same_state(atoms, start)
    assert_buffers_empty(dyn)


# -- across machines ---------------------------------------------------------

LEGS = f'''
import hashlib, json, sys
import numpy as np
from ase import units
from ase.io import read
from ase_reversible import LennardJones, ReversibleBussi
from ase_reversible.app.systems import argon_cluster
from ase_reversible.core.noise import BussiDraws, portable_log, step_key
from ase_reversible.md.bussi import alpha_ratio

def lj():
    return LennardJones(sigma={AR_SIGMA!r}, epsilon={AR_EPSILON!r},
                        rc={AR_RC!r})

leg = sys.argv[1] if len(sys.argv) > 1 else LEG
if leg == 'write':
    atoms = argon_cluster(3, 20)
    atoms.calc = lj()
    dyn = ReversibleBussi(atoms, 5 * units.fs, 300, 40 * units.fs, seed=8,
                          trajectory='run.traj', loginterval=40)
    dyn.run(40)
    dyn.write_buffer('buffer.npz')
    dyn.close()
    print('{{}}')
else:
    draws = BussiDraws(165)
    key = step_key(8, 5 * units.fs)
    bits = [alpha_ratio(1.0 + k / 7, 0.0258, 0.9, *draws(key, k))
            for k in range(300)]
    first, frame = read('run.traj', 0), read('run.traj', -1)
    frame.calc = lj()
    dyn = ReversibleBussi(frame, 5 * units.fs, 300, 40 * units.fs,
                          buffer='buffer.npz')
    dyn.run(40)
    h = hashlib.sha256(dyn.state.ix_nc.tobytes() + dyn.state.ip_nc.tobytes())
    dyn.reverse().run(80)
    back = bool(np.array_equal(frame.positions, first.positions)
                and np.array_equal(frame.get_momenta(), first.get_momenta()))
    x = np.random.default_rng(0).uniform(0.5, 3.0, (300, 3))
    print(json.dumps({{'ratios': bits, 'ahead': h.hexdigest(),
                      'back': back, 'exp': np.exp(x).tobytes().hex(),
                      'blas': (x.T @ x).tobytes().hex()}}))
'''


@SLOW
def test_the_same_bits_on_another_machine(tmp_path):
    """Leg 1 (native) writes a heating run's frame and buffer; legs on
    'native' and 'sse4' each compute 300 ratios from the draws, continue
    40 steps and run back 80 to the start: the same bits on both."""
    run_leg('native', "LEG = 'write'\n" + LEGS, tmp_path)
    out = {m: json.loads(run_leg(m, "LEG = 'go'\n" + LEGS,
                                 tmp_path).strip().splitlines()[-1])
           for m in ('native', 'sse4')}
    # The two legs are different machines: BLAS (and, where this CPU has
    # the SIMD targets 'sse4' switches off, np.exp) gave other bits.
    assert out['native'].pop('blas') != out['sse4'].pop('blas') or \
        out['native']['exp'] != out['sse4']['exp']
    out['native'].pop('exp'), out['sse4'].pop('exp')
    assert out['native'] == out['sse4']
    assert out['native']['back']
    assert len(set(out['native']['ratios'])) > 250


# -- sampling -----------------------------------------------------------------

def gamma_cdf(x, shape, scale):
    """The regularized lower incomplete gamma P(shape, x / scale): its
    power series below shape + 1, Legendre's continued fraction (by
    Lentz's method) above."""
    z = x / scale
    if z <= 0:
        return 0.0
    front = math.exp(shape * math.log(z) - z - math.lgamma(shape))
    if z < shape + 1:
        term = total = 1.0 / shape
        k = shape
        while term > 1e-17 * total:
            k += 1
            term *= z / k
            total += term
        return front * total
    tiny = 1e-300
    b = z + 1 - shape
    c, d = 1 / tiny, 1 / b
    h = d
    for i in range(1, 10_000):
        a = -i * (i - shape)
        b += 2
        d = a * d + b
        d = tiny if abs(d) < tiny else d
        c = b + a / c
        c = tiny if abs(c) < tiny else c
        d = 1 / d
        h *= d * c
        if abs(d * c - 1) < 1e-16:
            break
    return 1.0 - front * h


def gamma_ks_pvalue(samples, shape, scale, own=False):
    """Kolmogorov-Smirnov p-value of ``samples`` against Gamma(shape,
    scale): scipy.stats where present (and not ``own``), else the
    statistic with Stephens' small-sample correction and Kolmogorov's
    series."""
    try:
        from scipy import stats
    except ImportError:
        own = True
    if not own:
        return float(stats.kstest(samples, 'gamma',
                                  args=(shape, 0, scale)).pvalue)
    x = np.sort(np.asarray(samples, float))
    n = len(x)
    f = np.array([gamma_cdf(v, shape, scale) for v in x])
    d = max((np.arange(1, n + 1) / n - f).max(),
            (f - np.arange(n) / n).max())
    t = (math.sqrt(n) + 0.12 + 0.11 / math.sqrt(n)) * d
    return float(min(1.0, max(0.0, 2 * sum(
        (-1) ** (k - 1) * math.exp(-2 * k * k * t * t)
        for k in range(1, 101)))))


def test_the_own_ks_test_agrees_with_scipy():
    """The fallback used where scipy is missing, against scipy here."""
    stats = pytest.importorskip('scipy.stats', reason='scipy to compare')
    rng = np.random.default_rng(3)
    for shape in (1.5, 382.5):
        assert gamma_cdf(shape * 1.1, shape, 2.0) == pytest.approx(
            stats.gamma(shape, scale=2.0).cdf(shape * 1.1), rel=1e-10)
        for bias in (1.0, 1.02):
            samples = rng.gamma(shape * bias, 2.0, size=300)
            assert gamma_ks_pvalue(samples, shape, 2.0, own=True) == \
                pytest.approx(gamma_ks_pvalue(samples, shape, 2.0),
                              rel=0.1, abs=1e-3)


def liquid_argon():
    """256 Ar atoms at 1.37 g/cm3, drawn at 600 K: a liquid once a
    thermostat has cooled it to 90 K (rms displacement 3.8 A in 10 ps,
    measured; benchmarks/thermostat.py uses the same system)."""
    atoms = argon_bulk((4, 4, 4), 600, seed=1)
    atoms.set_cell(atoms.cell * 1.10, scale_atoms=True)
    return atoms


@SLOW
def test_canonical_kinetic_energy_for_liquid_argon_and_copper_as_ases():
    """Liquid Ar256 and crystalline Cu256 (asap3), both thermostats with
    FixCom (3N - 3 degrees of freedom, which both count): after
    equilibration the kinetic energy against Gamma((3N - 3) / 2, kT) by
    KS on every 20th of 4000 steps, and the mean within 4 standard errors
    (20 blocks), for ReversibleBussi and ASE's Bussi alike."""
    asap3 = pytest.importorskip('asap3', reason='asap3 for 256 atoms')
    cases = ((liquid_argon,
              lambda: asap3.LennardJones([18], [AR_EPSILON], [AR_SIGMA],
                                         rCut=AR_RC, modified=True),
              10, 90, 1e-13),
             (lambda: copper_bulk((4, 4, 4), 600, seed=1), asap3.EMT, 5,
              600, None))
    for build, calc, dt, temperature, force_noise in cases:
        for kind in ('reversible', 'ase'):
            atoms = build()
            atoms.set_constraint(FixCom())
            atoms.calc = calc()
            if kind == 'reversible':
                dyn = ReversibleBussi(atoms, dt * units.fs, temperature,
                                      100 * units.fs, seed=21,
                                      force_noise=force_noise)
            else:
                dyn = Bussi(atoms, dt * units.fs, temperature,
                            100 * units.fs, rng=np.random.default_rng(21))
            dyn.run(1000)
            kinetic = []
            dyn.attach(lambda: kinetic.append(atoms.get_kinetic_energy()))
            dyn.run(4000)
            kinetic = np.array(kinetic[:4000])
            kT = units.kB * temperature
            dof = atoms.get_number_of_degrees_of_freedom()
            assert dof == 3 * len(atoms) - 3
            p = gamma_ks_pvalue(kinetic[::20], dof / 2, kT)
            blocks = kinetic.reshape(20, -1).mean(axis=1)
            error = blocks.std(ddof=1) / math.sqrt(20)
            assert p > 1e-3, (kind, temperature, p)
            assert abs(blocks.mean() - dof * kT / 2) < 4 * error, \
                (kind, temperature)


def test_the_thermostat_page_holds_the_stored_bussi_numbers():
    """docs/thermostats.md's Bussi block holds numbers (read from the
    Markdown: ``python benchmarks/render.py --check``, a CI step, checks
    that they are what docs/benchmarks/thermostat.json renders to)."""
    import json
    import re
    from pathlib import Path
    docs = Path(__file__).resolve().parent.parent / 'docs'
    stored = json.loads((docs / 'benchmarks' / 'thermostat.json').read_text())
    assert 'bussi' in stored['results']
    page = (docs / 'thermostats.md').read_text()
    begin = '<!-- thermostat bussi: written by benchmarks/render.py'
    assert page.count(begin) == 1
    inside = page.split(begin)[1].split('<!-- end of thermostat bussi -->')[0]
    assert re.search(r'p = \d', inside) and 'state equal' in inside
