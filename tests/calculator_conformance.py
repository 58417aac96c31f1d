"""What every calculator run by ReversibleVerlet is checked for.

Subclass :class:`CalculatorConformance` as ``Test<Something>`` in a test
module, give it ``systems`` and ``make_calc``, and pytest runs each check
on each system.  A check that does not apply to a calculator (it has no
``hessian_vector_product``, does not declare ``forces_are_pure``, ...) is
skipped with the reason, so a third-party calculator can be run through
the same class.

Exactness is asserted with :func:`numpy.array_equal`; derivatives against
finite differences with tolerances, set per calculator.
"""

import numpy as np
import pytest
from ase.calculators.calculator import PropertyNotImplementedError

from ase_reversible import ReversibleVerlet, probe_purity

from exactness import assert_runs_back
from finite_differences import energy_gradient, hessian_times
from tiers import tiered


class CalculatorConformance:
    """Checks shared by all calculators; subclass and fill in the hooks.

    Hooks
    -----
    systems : dict
        Name -> function of no arguments returning fresh ``ase.Atoms``
        with momenta and no calculator.  Every check runs on each.
    make_calc(**parameters)
        A fresh calculator.
    timestep : float
        ASE time units, for the runs with ReversibleVerlet.
    reversal_steps : int or dict
        Steps out (and as many back) in the reversal check; a dict gives
        them per system.
    exact_check_state : bool
        Whether ``check_state`` sees a 1-ulp move (ASE's default does not).
    external_field : bool
        True if the forces need not sum to zero (gravity, a wall).
    masses_matter : bool
        True if the forces depend on the masses (so must ``check_state``).
    gradient_tolerance, hessian_tolerance : float
        Largest error of finite differences, relative to max|F| and
        max|Hv|.
    parameter_derivative_tolerance : float
        Likewise for ``force_parameter_derivative``.
    held_fixed : dict
        Parameters passed explicitly while one is differentiated (so a
        default derived from it does not move along).
    parameter_change : dict or None
        A valid ``set(...)`` that changes the forces.
    bad_parameters : list
        ``(kwargs, exception type(s), match)`` the constructor must refuse.
    """

    systems = {}
    timestep = 0.01
    reversal_steps = 500
    exact_check_state = True
    external_field = False
    masses_matter = False
    gradient_tolerance = 1e-8
    hessian_tolerance = 1e-8
    parameter_derivative_tolerance = 1e-7
    held_fixed = {}
    parameter_change = None
    bad_parameters = []

    def make_calc(self, **parameters):
        raise NotImplementedError

    # -- plumbing ---------------------------------------------------------

    def pytest_generate_tests(self, metafunc):
        if 'system' in metafunc.fixturenames:
            metafunc.parametrize('system', sorted(self.systems))

    @pytest.fixture
    def atoms(self, system):
        atoms = self.systems[system]()
        atoms.calc = self.make_calc()
        return atoms

    @staticmethod
    def _needs(condition, reason):
        if not condition:
            pytest.skip(reason)

    def _hvp(self, atoms):
        hvp = getattr(atoms.calc, 'hessian_vector_product', None)
        self._needs(callable(hvp), 'no hessian_vector_product')
        return hvp

    # -- the model --------------------------------------------------------

    def test_forces_are_minus_the_energy_gradient(self, atoms):
        f_nc = atoms.get_forces(apply_constraint=False)
        grad_nc = energy_gradient(atoms, 1e-5)  # Å
        # Central differences: truncation ~h² |E'''| plus rounding of E
        # over h, both far below the tolerance (measured per calculator).
        assert np.abs(f_nc + grad_nc).max() < \
            self.gradient_tolerance * np.abs(f_nc).max()

    def test_energies_add_up_to_the_energy(self, atoms):
        try:
            energies_n = atoms.get_potential_energies()
        except (PropertyNotImplementedError, NotImplementedError):
            pytest.skip('no per-atom energies')
        assert energies_n.shape == (len(atoms),)
        assert np.isclose(energies_n.sum(), atoms.get_potential_energy(),
                          rtol=1e-13, atol=1e-12)

    def test_forces_balance(self, atoms):
        self._needs(not self.external_field, 'an external field')
        f_nc = atoms.get_forces(apply_constraint=False)
        # Pair terms cancel: the total force is rounding noise.
        assert np.abs(f_nc.sum(axis=0)).max() < 1e-12 * np.abs(f_nc).max()

    # -- state and purity -------------------------------------------------

    def test_a_one_ulp_move_is_seen_and_recomputed(self, atoms):
        self._needs(self.exact_check_state,
                    "ASE's check_state ignores moves below 1e-15 Å")
        f_nc = atoms.get_forces(apply_constraint=False)
        assert atoms.calc.check_state(atoms) == []
        # A fine fixed-point grid makes moves this small.
        atoms.positions[1, 0] = np.nextafter(atoms.positions[1, 0], np.inf)
        assert atoms.calc.check_state(atoms) == ['positions']
        moved_nc = atoms.get_forces(apply_constraint=False)
        assert atoms.calc.check_state(atoms) == []
        fresh = atoms.copy()
        fresh.calc = self.make_calc()
        assert np.array_equal(moved_nc,
                              fresh.get_forces(apply_constraint=False))
        assert not np.array_equal(moved_nc, f_nc)

    def test_masses_are_part_of_the_state(self, atoms):
        self._needs(self.masses_matter, 'the forces ignore masses')
        f_nc = atoms.get_forces(apply_constraint=False)
        atoms.set_masses(2 * atoms.get_masses())
        assert atoms.calc.check_state(atoms) == ['masses']
        assert not np.array_equal(atoms.get_forces(apply_constraint=False),
                                  f_nc)

    def test_forces_do_not_depend_on_history(self, atoms):
        self._needs(getattr(atoms.calc, 'forces_are_pure', False) is True,
                    'does not declare forces_are_pure (ReversibleVerlet '
                    'probes it or sorts its lists: tests/test_purity.py)')
        x0_nc = atoms.get_positions()
        f0_nc = atoms.get_forces(apply_constraint=False)
        # Far enough for neighbour searches to run again, then back.
        rng = np.random.default_rng(3)
        for scale in (0.05, 1.0):
            atoms.positions = x0_nc + rng.normal(0.0, scale, x0_nc.shape)
            atoms.get_forces(apply_constraint=False)
            atoms.positions = x0_nc
            assert np.array_equal(atoms.get_forces(apply_constraint=False),
                                  f0_nc)
        assert probe_purity(atoms, trials=3) == 0.0
        assert ReversibleVerlet(atoms, self.timestep).force_purity.mode \
            == 'trust'

    # -- with ReversibleVerlet --------------------------------------------

    # Position Verlet is the same sub-steps in another order: the long
    # tier runs it for every calculator.
    @pytest.mark.parametrize('scheme', tiered(['velocity', 'position'],
                                              quick=['velocity']))
    def test_reversal_is_exact(self, atoms, system, scheme):
        steps = self.reversal_steps
        if isinstance(steps, dict):
            steps = steps[system]
        fixed = [i for c in atoms.constraints
                 for i in c.get_indices()] if atoms.constraints else []
        dyn = ReversibleVerlet(atoms, self.timestep, scheme=scheme)
        x0_nc = atoms.get_positions()
        assert_runs_back(dyn, steps)
        assert np.array_equal(atoms.positions[fixed], x0_nc[fixed])

    # -- derivatives ------------------------------------------------------

    def test_hessian_vector_product_matches_finite_differences(self, atoms):
        hvp = self._hvp(atoms)
        x0_nc = atoms.get_positions()
        v_nc = np.random.default_rng(1).normal(size=x0_nc.shape)
        hv_nc = hvp(atoms, v_nc)
        fd_nc = hessian_times(atoms, v_nc, 1e-5)
        assert np.abs(hv_nc - fd_nc).max() < \
            self.hessian_tolerance * np.abs(hv_nc).max()
        assert np.array_equal(atoms.positions, x0_nc)

    def test_hessian_vector_product_is_symmetric(self, atoms):
        hvp = self._hvp(atoms)
        rng = np.random.default_rng(2)
        v_nc, w_nc = rng.normal(size=(2, len(atoms), 3))
        hv_nc, hw_nc = hvp(atoms, v_nc), hvp(atoms, w_nc)
        # Exact in real numbers; rounding is ~1e-16 relative.
        assert abs(np.vdot(w_nc, hv_nc) - np.vdot(v_nc, hw_nc)) < \
            1e-13 * np.linalg.norm(w_nc) * np.linalg.norm(hv_nc)

    def test_hessian_vector_product_refuses_a_wrong_shape(self, atoms):
        hvp = self._hvp(atoms)
        with pytest.raises(ValueError, match='shape'):
            hvp(atoms, np.zeros((len(atoms) - 1, 3)))

    def test_force_parameter_derivatives_match_finite_differences(
            self, atoms):
        names = tuple(getattr(atoms.calc, 'differentiable_parameters', ()))
        self._needs(names, 'no differentiable_parameters')
        for name in names:
            derivative_nc = atoms.calc.force_parameter_derivative(atoms,
                                                                  name)
            value = atoms.calc.parameters[name]
            h = 1e-6 * value

            def forces_at(theta):
                calc = self.make_calc(**self.held_fixed)
                calc.set(**{name: theta})
                return calc.get_forces(atoms)

            fd_nc = (forces_at(value + h) - forces_at(value - h)) / (2 * h)
            error = np.abs(derivative_nc - fd_nc).max() \
                / np.abs(derivative_nc).max()
            assert error < self.parameter_derivative_tolerance, name
        with pytest.raises(ValueError, match='available'):
            atoms.calc.force_parameter_derivative(atoms, 'no such parameter')

    def test_vector_jacobian_product_matches_finite_differences(
            self, atoms):
        calc = atoms.calc
        self._needs(callable(getattr(calc, 'vector_jacobian_product', None)),
                    'no vector_jacobian_product')
        names = tuple(getattr(calc, 'differentiable_parameters', ()))
        x0_nc = atoms.get_positions()
        v_nc = np.random.default_rng(4).normal(size=x0_nc.shape)
        dx_nc, dtheta = calc.vector_jacobian_product(atoms, v_nc, names)
        assert np.array_equal(atoms.positions, x0_nc)
        assert sorted(dtheta) == sorted(names)
        # (dF/dx)^T v = -H v: H is symmetric.
        fd_nc = -hessian_times(atoms, v_nc, 1e-5)
        assert np.abs(dx_nc - fd_nc).max() < \
            self.hessian_tolerance * np.abs(dx_nc).max()
        for name in names:
            value = calc.parameter_values([name])[name]
            h = 1e-6 * value

            def along_v(theta):
                other = self.make_calc(**self.held_fixed)
                other.set_parameter_values({name: theta})
                return np.vdot(other.get_forces(atoms), v_nc)

            fd = (along_v(value + h) - along_v(value - h)) / (2 * h)
            scale = np.abs(calc.force_parameter_derivative(atoms, name)).max() \
                * np.abs(v_nc).sum()
            assert abs(dtheta[name] - fd) < \
                self.parameter_derivative_tolerance * scale, name
        with pytest.raises(ValueError, match='available'):
            calc.vector_jacobian_product(atoms, v_nc, ['no such parameter'])

    def test_parameter_values_round_trip_and_changes_are_seen(self, atoms):
        calc = atoms.calc
        names = tuple(getattr(calc, 'differentiable_parameters', ()))
        self._needs(names and callable(getattr(calc, 'set_parameter_values',
                                                None)),
                    'no differentiable parameters to set')
        values = calc.parameter_values()
        assert sorted(values) == sorted(names)
        f_nc = atoms.get_forces(apply_constraint=False)
        before = dict(calc.parameters)
        name = names[0]
        calc.set_parameter_values({name: 1.01 * values[name]})
        assert calc.parameter_values([name])[name] == 1.01 * values[name]
        assert dict(calc.parameters) != before  # what the watch compares
        assert not np.array_equal(atoms.get_forces(apply_constraint=False),
                                  f_nc)
        calc.set_parameter_values(values)
        assert np.array_equal(atoms.get_forces(apply_constraint=False), f_nc)
        with pytest.raises(ValueError, match='scalar|shape'):
            calc.set_parameter_values({name: [1.0, 2.0]})
        with pytest.raises(ValueError, match='available'):
            calc.set_parameter_values({'no such parameter': 1.0})
        assert calc.parameter_values() == values

    # -- parameters -------------------------------------------------------

    def test_a_changed_parameter_changes_the_results(self, atoms):
        self._needs(self.parameter_change, 'no parameter to change')
        f_nc = atoms.get_forces(apply_constraint=False)
        energy = atoms.get_potential_energy()
        atoms.calc.set(**self.parameter_change)
        fresh = atoms.copy()
        fresh.calc = self.make_calc(**self.parameter_change)
        expected_nc = fresh.get_forces(apply_constraint=False)
        assert np.array_equal(atoms.get_forces(apply_constraint=False),
                              expected_nc)
        assert not np.array_equal(expected_nc, f_nc)
        assert atoms.get_potential_energy() == fresh.get_potential_energy()
        assert atoms.get_potential_energy() != energy

    def test_bad_parameters_are_refused(self):
        self._needs(self.bad_parameters, 'no parameters are checked')
        for kwargs, error, match in self.bad_parameters:
            with pytest.raises(error, match=match):
                self.make_calc(**kwargs)
            # set() checks them the same way, and a refused set changes
            # nothing.
            calc = self.make_calc()
            before = dict(calc.parameters)
            with pytest.raises(error, match=match):
                calc.set(**kwargs)
            assert dict(calc.parameters) == before
