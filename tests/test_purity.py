"""Force purity: the problem is real, and each remedy removes it."""

import re
import sys

import numpy as np
import pytest
from ase.calculators.calculator import Calculator, all_changes
from ase.calculators.emt import EMT
from ase.calculators.lj import LennardJones
from ase.calculators.mixing import (LinearCombinationCalculator,
                                    MixedCalculator, SumCalculator)
from ase.calculators.morse import MorsePotential

from ase_reversible import ImpureForcesError, ReversibleVerlet, probe_purity
from ase_reversible.purity import (DEFAULT_FORCE_NOISE, MEASURED_NOISE_FLOOR,
                                   SPOT_CHECK_INTERVAL, GuardedForces,
                                   SortedNeighborListForces, TrustedForces,
                                   force_provider, measured_force_noise)

from conftest import (AR_EPSILON, AR_RC, AR_SIGMA, CALCULATORS, DT, argon_bulk,
                      argon_cluster, copper_bulk)
from exactness import (assert_atoms_show_committed_state, assert_runs_back,
                       assert_same_state, forward_and_back, snapshot)
from tiers import SLOW


def forces_after_history(atoms, provider, seed):
    """Forces at atoms' positions after the calculator saw other positions."""
    rng = np.random.default_rng(seed)
    x_nc = atoms.positions.copy()
    atoms.positions = x_nc + rng.normal(0, 0.2, x_nc.shape) + rng.uniform(-2, 2, 3)
    provider.forces(atoms)
    atoms.positions = x_nc + rng.normal(0, 0.05, x_nc.shape)
    provider.forces(atoms)
    atoms.positions = x_nc
    return provider.forces(atoms).copy()


@pytest.mark.parametrize('system, calc', [
    (lambda: copper_bulk((3, 3, 3)), 'ase-emt'),
    (lambda: argon_bulk((2, 2, 2)), 'ase-lj'),
])
def test_sorted_lists_make_ase_forces_history_independent(system, calc):
    # Atoms on lattice sites sit on the cell faces, where a list built
    # elsewhere wraps them differently.
    def fresh_atoms():
        atoms = system()
        atoms.calc = CALCULATORS[calc]()
        return atoms

    for provider in (TrustedForces, SortedNeighborListForces):
        reference = provider().forces(fresh_atoms()).copy()
        after = [forces_after_history(fresh_atoms(), provider(), seed)
                 for seed in range(3)]
        same = all(np.array_equal(f, reference) for f in after)
        # The control shows the history dependence exists for this system;
        # sorting removes it.
        assert same == (provider is SortedNeighborListForces)


def test_probe_sees_asap3_noise_on_periodic_copper():
    atoms = copper_bulk((5, 5, 5))
    atoms.calc = CALCULATORS['asap-emt']()
    noise = probe_purity(atoms)
    assert 0 < noise < GuardedForces().force_noise


def test_auto_mode_choices():
    for calc, mode in [('ase-lj', 'sorted'), ('ase-emt', 'sorted'),
                       ('asap-lj', 'guarded'), ('asap-emt', 'guarded')]:
        atoms = copper_bulk((4, 4, 4)) if 'emt' in calc else argon_cluster(3, 50)
        atoms.calc = CALCULATORS[calc]()
        assert ReversibleVerlet(atoms, DT).force_purity.mode == mode


class HiddenEMT(Calculator):
    """ASE's EMT behind a plain wrapper that does not say what it holds
    (no ``.calcs``): to the integrator, an unknown calculator."""

    implemented_properties = ['energy', 'forces']

    def __init__(self):
        super().__init__()
        self.inner = EMT()

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        self.results = {'energy': self.inner.get_potential_energy(atoms),
                        'forces': self.inner.get_forces(atoms)}


class WarmStartedLJ(LennardJones):
    """ASE's LennardJones with forces refined from the previous call's, as a
    self-consistent field that starts from its last solution is."""

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        exact = self.results['forces']
        guess = getattr(self, 'guess', None)
        if guess is None or guess.shape != exact.shape:
            guess = np.zeros_like(exact)
        for _ in range(8):
            guess = guess + 0.5 * (exact - guess)
        self.guess = self.results['forces'] = guess


@SLOW
def test_auto_mode_refuses_summation_noise_and_points_to_guarded():
    # The unsorted neighbour list inside makes the forces history dependent
    # by a few ulps, on atoms that sit on the cell faces.
    atoms = copper_bulk((5, 5, 5))
    atoms.calc = HiddenEMT()
    x_nc, p_nc = atoms.get_positions(), atoms.get_momenta()
    with pytest.raises(ImpureForcesError,
                       match="floating-point sums.*force_purity='guarded', "
                             "force_noise=") as refused:
        ReversibleVerlet(atoms, DT)
    assert np.array_equal(atoms.positions, x_nc)
    assert np.array_equal(atoms.get_momenta(), p_nc)
    # The remedy the message gives works.
    noise = re.search(r"force_noise=([0-9.e+-]+)", str(refused.value))
    dyn = ReversibleVerlet(atoms, DT, force_purity='guarded',
                           force_noise=float(noise.group(1)))
    assert_runs_back(dyn, 100)


def test_auto_mode_refuses_scf_history_and_points_to_a_cold_start():
    atoms = argon_cluster(2, 50)
    atoms.calc = WarmStartedLJ(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    with pytest.raises(ImpureForcesError) as refused:
        ReversibleVerlet(atoms, DT)
    message = str(refused.value)
    assert 'self-consistent field' in message and 'from scratch' in message
    # Refined again at the same positions its forces change too, but far
    # less: history, not run-to-run nondeterminism.
    assert 'depend on its history' in message
    assert 'run-to-run' not in message
    assert "force_purity='guarded'" not in message


@pytest.mark.parametrize('mix', [
    lambda calc: SumCalculator([calc]),
    lambda calc: LinearCombinationCalculator([calc], [1.0]),
    lambda calc: MixedCalculator(calc, CALCULATORS['ase-lj'](), 1.0, 0.0),
], ids=['sum', 'linear-combination', 'mixed'])
def test_mixing_calculators_get_their_members_sorted(mix):
    # Probed as a whole, SumCalculator([EMT()]) passed while no atom was
    # near a periodic face and was trusted; its members' lists are sorted
    # now, whatever the probe would see.
    atoms = argon_cluster(2, 50)
    atoms.calc = mix(CALCULATORS['ase-lj']())
    dyn = ReversibleVerlet(atoms, DT)
    assert dyn.force_purity.mode == 'sorted'
    assert_runs_back(dyn, 100)


class Summed(Calculator):
    """A user's own mixing calculator: the sum of the members in ``.calcs``."""

    implemented_properties = ['energy', 'forces']

    def __init__(self, calcs):
        super().__init__()
        self.calcs = calcs

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        self.results = {
            'energy': sum(c.get_potential_energy(atoms) for c in self.calcs),
            'forces': sum(c.get_forces(atoms) for c in self.calcs)}


@SLOW
def test_a_mixture_is_handled_as_its_strictest_member():
    # Chosen from the members alone, before any force call: asap3 inside
    # means guarded rounding (asap3 calculators do not work inside ASE's
    # own mixers, so a user's wrapper stands in).
    atoms = copper_bulk((3, 3, 3), 600)
    atoms.calc = Summed([EMT(), CALCULATORS['asap-emt']()])
    assert force_provider(atoms).mode == 'guarded'
    atoms.calc = Summed([EMT(), Summed([EMT()])])
    assert force_provider(atoms).mode == 'sorted'
    assert_runs_back(ReversibleVerlet(atoms, DT), 100)
    assert all(c.nl.nl.sorted for c in (atoms.calc.calcs[0],
                                        atoms.calc.calcs[1].calcs[0]))


def test_auto_mode_trusts_an_unknown_pure_calculator():
    atoms = argon_cluster(2, 50)
    atoms.calc = MorsePotential(epsilon=0.0104, r0=3.8, rho0=6.0)
    dyn = ReversibleVerlet(atoms, DT)
    assert dyn.force_purity.mode == 'trust'
    assert_runs_back(dyn, 100)


@SLOW
def test_without_purity_handling_asap3_reversal_fails():
    # The control for the guarded mode: the same run with forces trusted
    # and the spot check that would object (below) switched off.
    atoms = copper_bulk((5, 5, 5), 600)
    atoms.calc = CALCULATORS['asap-emt']()
    dyn = ReversibleVerlet(atoms, DT, force_purity='trust',
                           momentum_quantum=2.0**-40)
    dyn.force_purity.spot_check = None
    start, _ = forward_and_back(dyn, 1000)
    assert not (np.array_equal(atoms.positions, start[0])
                and np.array_equal(atoms.get_momenta(), start[1]))


def test_trusting_asap3_is_stopped_by_the_spot_check():
    atoms = copper_bulk((5, 5, 5), 600)
    atoms.calc = CALCULATORS['asap-emt']()
    dyn = ReversibleVerlet(atoms, DT, force_purity='trust',
                           momentum_quantum=2.0**-40)
    with pytest.raises(ImpureForcesError,
                       match=r"force_purity='trust'.*bit for bit.*"
                             r"step was not taken"):
        dyn.run(1000)
    # Kept at the interval's end, checked half an interval later.
    assert 0 < dyn.nsteps <= SPOT_CHECK_INTERVAL * 3 // 2
    assert dyn.force_purity.spot_check.checks == 1
    assert_atoms_show_committed_state(dyn)


class LateNoiseLJ(LennardJones):
    """ASE's LennardJones whose sums, after its first ``quiet`` calls, are
    off by -1, 0 or +1 in the last bit, at random per component and call,
    as parallel sums whose order depends on the threads are: the probe at
    construction sees none of it."""

    quiet = 40

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        self.calls = getattr(self, 'calls', 0) + 1
        if self.calls > self.quiet:
            forces = self.results['forces']
            rng = np.random.default_rng(self.calls)
            forces += rng.integers(-1, 2, forces.shape) * np.spacing(forces)


@SLOW
def test_call_to_call_noise_that_passed_the_probe_is_caught_during_the_run():
    atoms = argon_cluster(3, 50)
    atoms.calc = LateNoiseLJ(sigma=AR_SIGMA, epsilon=AR_EPSILON, rc=AR_RC)
    dyn = ReversibleVerlet(atoms, DT)  # the probe passed: no error
    assert dyn.force_purity.mode == 'sorted'  # its lists, all the same
    with pytest.raises(ImpureForcesError, match='OMP_NUM_THREADS=1'):
        dyn.run(2 * SPOT_CHECK_INTERVAL)
    assert 0 < dyn.nsteps < 2 * SPOT_CHECK_INTERVAL
    assert_atoms_show_committed_state(dyn)


@SLOW
def test_a_pure_calculator_passes_its_spot_checks_and_runs_back():
    atoms = argon_cluster(2, 50)
    atoms.calc = MorsePotential(epsilon=0.0104, r0=3.8, rho0=6.0)
    dyn = ReversibleVerlet(atoms, DT)
    assert dyn.force_purity.mode == 'trust'
    assert_runs_back(dyn, 2 * SPOT_CHECK_INTERVAL)
    assert dyn.force_purity.spot_check.checks >= 3


def test_guarded_noise_beyond_its_bound_is_caught_by_the_spot_check():
    atoms = copper_bulk((5, 5, 5), 600)
    atoms.calc = CALCULATORS['asap-emt']()
    dyn = ReversibleVerlet(atoms, DT, force_noise=1e-17)
    with pytest.raises(ImpureForcesError, match='force_noise='):
        dyn.run(2 * SPOT_CHECK_INTERVAL)
    assert_atoms_show_committed_state(dyn)


@SLOW
def test_guarded_mode_recomputes_rarely_and_sees_noise_below_its_bound():
    atoms = copper_bulk((5, 5, 5), 600)
    atoms.calc = CALCULATORS['asap-emt']()
    dyn = ReversibleVerlet(atoms, DT)
    start, moved = forward_and_back(dyn, 1000)
    assert_same_state(atoms, start)
    guard = dyn.force_purity
    assert 0 < guard.clean_recomputations < 0.05 * 2000
    assert guard.max_observed_noise < guard.force_noise / 8


def test_guarded_mode_with_a_fine_grid_recomputes_often_but_stays_exact():
    atoms = argon_cluster(3, 120)
    atoms.calc = CALCULATORS['asap-lj']()
    # Fine for the fixed bound (the measured one would allow this grid).
    dyn = ReversibleVerlet(atoms, DT, momentum_quantum=2.0**-40,
                           force_noise=DEFAULT_FORCE_NOISE)
    assert_runs_back(dyn, 500)
    assert dyn.force_purity.clean_recomputations > 100


@pytest.mark.parametrize('calc', ['asap-emt', 'asap-lj'])
def test_clean_forces_equal_a_fresh_calculators_bit_for_bit(calc):
    atoms = (copper_bulk((5, 5, 5), 600) if calc == 'asap-emt'
             else argon_bulk((4, 4, 4), 80))
    atoms.calc = CALCULATORS[calc]()
    fresh = atoms.copy()
    fresh.calc = CALCULATORS[calc]()
    f_fresh = fresh.get_forces()
    guard = GuardedForces()
    noisy = [forces_after_history(atoms, guard, seed) for seed in range(3)]
    # Control: the history really changes the last bits.
    assert any(not np.array_equal(f, f_fresh) for f in noisy)
    for seed in range(3):
        forces_after_history(atoms, guard, seed)
        assert np.array_equal(guard.clean_forces(atoms), f_fresh)


def test_guard_widens_with_the_coordinates_extent():
    # Noise grows with |x| (rounding of coordinate differences), so the
    # same kick that needs no clean recomputation near the origin needs
    # one far from it.
    from ase_reversible.purity import NOISE_REFERENCE_EXTENT

    def clean_recomputations(shift):
        atoms = argon_bulk((4, 4, 4), 80)
        atoms.positions += shift
        atoms.calc = CALCULATORS['asap-lj']()
        guard = GuardedForces()
        f_nc = guard.forces(atoms).copy()
        scale = 1.0
        # One component four times the origin's bound (force_noise x
        # max|F|) from a rounding boundary, the others on whole numbers.
        f_nc[:] = 0.0
        f_nc[0, 0] = 7.5 * (1 - 4 * guard.force_noise)
        out, scratch = np.empty_like(f_nc), np.empty_like(f_nc)
        try:
            guard.rounded_kick(atoms, f_nc, scale, lambda y: None, out,
                               scratch)
        except ImpureForcesError:
            pass  # the made-up forces differ from the clean ones by eV/Å
        return guard.clean_recomputations

    assert clean_recomputations(0.0) == 0
    assert clean_recomputations(8 * NOISE_REFERENCE_EXTENT) == 1


@pytest.mark.parametrize('mode', ['sorted', 'magic'])
def test_bad_purity_requests_are_refused(mode):
    atoms = argon_cluster(2, 50)
    atoms.calc = CALCULATORS['asap-lj']()
    with pytest.raises(ValueError, match='force_purity'):
        ReversibleVerlet(atoms, DT, force_purity=mode)


@pytest.mark.parametrize('shells', [2, 4])
def test_auto_measures_a_fine_bound_for_asap3_on_a_cluster_and_stays_exact(
        shells):
    # asap3 LennardJones on a free cluster shows almost no history noise:
    # 'auto' measures it and takes a bound far below the fixed one, so the
    # momentum quantum is far finer, and the run still comes back exactly.
    def cluster():
        atoms = argon_cluster(shells, 60)
        atoms.calc = CALCULATORS['asap-lj']()
        return atoms

    fixed = ReversibleVerlet(cluster(), DT, force_noise=DEFAULT_FORCE_NOISE)
    dyn = ReversibleVerlet(cluster(), DT)
    assert dyn.force_purity.force_noise == MEASURED_NOISE_FLOOR
    assert (dyn.grid.momentum_quantum
            <= 2.0**-10 * fixed.grid.momentum_quantum)
    assert_runs_back(dyn, 2000)
    assert dyn.force_purity.max_observed_noise <= MEASURED_NOISE_FLOOR / 8


def test_auto_keeps_the_fixed_bound_where_the_noise_is_near_it():
    atoms = copper_bulk((5, 5, 5), 600)
    atoms.calc = CALCULATORS['asap-emt']()
    noise = measured_force_noise(atoms)
    assert noise == DEFAULT_FORCE_NOISE


class FarArrivalNoise(LennardJones):
    """ASE's LennardJones with history noise of a known size: every force
    component is ``eps`` eV/Å larger when the atoms arrived from more than
    1 Å away (as they do for the guard's clean recomputation, which goes
    8 Å away and back), and as computed after the small moves of a step."""

    def __init__(self, eps, **kwargs):
        super().__init__(**kwargs)
        self.eps = eps
        self._last_nc = None

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        x_nc = self.atoms.positions
        far = (self._last_nc is not None
               and np.abs(x_nc - self._last_nc).max() > 1.0)
        self._last_nc = x_nc.copy()
        if far:
            self.results['forces'] = self.results['forces'] + self.eps


NOISE = 1e-10  # eV/Å, FarArrivalNoise's


def suggested_force_noise(message, seen):
    """The force_noise a message tells the user to pass, checked to be
    sixteen times the noise ``seen`` rounded up (to two digits: at most
    10% up) and big enough that the noise is no longer near it."""
    value = float(re.search(r'force_noise=([0-9.e+-]+) \(eV/Å, sixteen',
                            message).group(1))
    assert 16 * seen <= value <= 1.1 * 16 * seen
    return value


def noisy_guarded_run(noise_per_bound):
    """An argon cluster under FarArrivalNoise, guarded with a bound of
    NOISE / noise_per_bound, on a momentum grid fine enough that most
    kicks need a clean recomputation (which measures the noise).  Its
    forces stay below 1 eV/Å and its coordinates below 32 Å, so the bound
    is force_noise unscaled."""
    atoms = argon_cluster(2, 100)
    atoms.calc = FarArrivalNoise(NOISE, sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                 rc=AR_RC)
    assert np.abs(atoms.positions).max() < 32
    return ReversibleVerlet(atoms, DT, force_purity='guarded',
                            force_noise=NOISE / noise_per_bound,
                            momentum_quantum=2.0**-30)


def test_noise_near_the_bound_warns_at_the_users_line_with_the_value_to_use():
    dyn = noisy_guarded_run(noise_per_bound=1 / 1.5)
    start = snapshot(dyn.atoms)
    with pytest.warns(RuntimeWarning, match='force_noise=') as seen:
        dyn.run(20)  # the line the warning must name
    line = sys._getframe().f_lineno - 1
    assert dyn.force_purity.clean_recomputations > 0
    assert (NOISE / 2 < dyn.force_purity.max_observed_noise
            <= dyn.force_purity.force_noise)
    near = [w for w in seen if 'Force noise' in str(w.message)]
    assert len(near) == 1  # once per integrator
    assert near[0].filename == __file__ and near[0].lineno == line
    suggested_force_noise(str(near[0].message),
                          dyn.force_purity.max_observed_noise)
    # Still exact: the noise stayed within the bound.
    dyn.reverse()
    dyn.run(20)
    assert_same_state(dyn.atoms, start)


def test_the_warning_names_the_users_line_from_irun_too():
    dyn = noisy_guarded_run(noise_per_bound=1 / 1.5)
    with pytest.warns(RuntimeWarning, match='force_noise=') as seen:
        for _ in dyn.irun(20):  # the line the warning must name
            line = sys._getframe().f_lineno - 1
    near = [w for w in seen if 'Force noise' in str(w.message)]
    assert near[0].filename == __file__ and near[0].lineno == line


@pytest.mark.filterwarnings('error')
def test_noise_far_below_the_bound_runs_back_under_warnings_as_errors():
    # A quarter of the bound: the old threshold (an eighth) stopped this
    # valid run under -W error; "near" is now within a factor of 2.
    dyn = noisy_guarded_run(noise_per_bound=1 / 4)
    start = snapshot(dyn.atoms)
    dyn.run(20)
    guard = dyn.force_purity
    assert guard.clean_recomputations > 0
    assert guard.force_noise / 8 < guard.max_observed_noise \
        <= guard.force_noise / 2
    dyn.reverse()
    dyn.run(20)
    assert_same_state(dyn.atoms, start)


def test_noise_beyond_the_bound_stops_the_run_with_the_value_to_use():
    dyn = noisy_guarded_run(noise_per_bound=2)
    with pytest.raises(ImpureForcesError, match='force_noise=') as error:
        dyn.run(20)
    assert_atoms_show_committed_state(dyn)
    suggested_force_noise(str(error.value),
                          dyn.force_purity.max_observed_noise)


class BlasThreadNoise(LennardJones):
    """ASE's LennardJones whose forces, while BLAS may run more than one
    thread, differ from call to call in the last bits (every other call
    scaled by 1 + 2**-50), as sums split over threads do."""

    def __init__(self, **kwargs):
        from threadpoolctl import ThreadpoolController
        super().__init__(**kwargs)
        self.calls = 0
        self.threads_seen = set()
        self._blas = ThreadpoolController().select(user_api='blas')

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        self.calls += 1
        threads = max(lib['num_threads'] for lib in self._blas.info())
        self.threads_seen.add(threads)
        if threads > 1 and self.calls % 2:
            self.results['forces'] = self.results['forces'] * (1 + 2.0**-50)


def test_noise_that_one_thread_removes_is_found_and_held_under_auto():
    from threadpoolctl import threadpool_limits
    atoms = argon_cluster(2, 100)
    atoms.calc = BlasThreadNoise(sigma=AR_SIGMA, epsilon=AR_EPSILON,
                                 rc=AR_RC)
    with threadpool_limits(limits=2, user_api='blas'):
        # Control: on two threads the noise is there for the probe to see.
        assert 0 < probe_purity(atoms) < 1e-13
        dyn = ReversibleVerlet(atoms, DT)
        assert dyn.force_purity.mode == 'sorted'
        assert dyn.force_purity.one_thread.libraries
        atoms.calc.threads_seen.clear()
        assert_runs_back(dyn, 30)
        assert atoms.calc.threads_seen == {1}  # every force call held
    # On one thread from the start there is nothing to hold.
    with threadpool_limits(limits=1, user_api='blas'):
        assert ReversibleVerlet(atoms, DT).force_purity.one_thread is None
