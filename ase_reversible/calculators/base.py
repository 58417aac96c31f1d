"""What the package's calculators share: exact state checks, checked
parameters, pure forces and an order-fixed sum of pair terms onto atoms.

:class:`~ase_reversible.ReversibleVerlet` reverses a run bit for bit only
if the forces at given positions are always the same bits.  Three things
can break that in an ASE calculator, and :class:`ExactCalculator` rules
each out once for all of its subclasses:

- ASE's default ``check_state`` treats moves below 1e-15 Å as none and
  ignores masses, so a calculator could hand back forces computed
  elsewhere; :meth:`ExactCalculator.check_state` compares bit for bit.
- A parameter changed with ``set`` must not leave the results of the old
  one behind: ASE's ``Calculator.set`` keeps them unless told otherwise.
- A sum whose order depends on history (a neighbour list built at
  another time, an unordered scatter) gives other bits for the same
  terms; :meth:`ExactCalculator.scatter_pairs` always adds in the given
  pair order.

The subclasses also compute with correctly rounded operations only (no
numpy powers, BLAS or libm: :mod:`ase_reversible.core.portable`), so their
results are the same bits on every CPU, not only on one.

Array names follow one convention in all the calculators: a suffix gives
the shape (``_nc``: ``[n_atoms, 3]``, ``_n``: ``[n_atoms]``, ``_pc``:
``[n_pairs, 3]``, ``_p``: ``[n_pairs]``), ``i_p`` and ``j_p`` index the two
atoms of each pair, and ``d_pc = x[j] - x[i]`` (plus an image shift where
there are images).
"""

from __future__ import annotations

import math

import numpy as np
from ase.calculators.calculator import Calculator, all_changes

from ..core.portable import dot

#: How to read each quantity :func:`exact_system_changes` can compare.
_SYSTEM_QUANTITIES = {
    'positions': lambda atoms: atoms.arrays['positions'],
    'numbers': lambda atoms: atoms.arrays['numbers'],
    'cell': lambda atoms: atoms.cell.array,
    'pbc': lambda atoms: atoms.pbc,
    'masses': lambda atoms: atoms.get_masses(),
}


def exact_system_changes(old, atoms, names):
    """Which of ``names`` differ between ``old`` and ``atoms``, bit for bit.

    ``names`` from ``'positions'``, ``'numbers'``, ``'cell'``, ``'pbc'``,
    ``'masses'``; returns a list of those that differ (all of ASE's
    ``all_changes`` if ``old`` is None or has another number of atoms).

    For a calculator's ``check_state``.  ASE's default treats positions
    within 1e-15 Å as unchanged, which a fine fixed-point grid can move
    by (stale forces would then break exact reversal), and its
    ``allclose`` costs more than the forces of a small system.
    """
    if old is None or len(old) != len(atoms):
        return list(all_changes)
    return [name for name in names
            if not np.array_equal(_SYSTEM_QUANTITIES[name](old),
                                  _SYSTEM_QUANTITIES[name](atoms))]


class ExactCalculator(Calculator):
    """Base of the package's calculators.

    A subclass declares

    - ``default_parameters`` and ``parameter_bounds``, a dict from each
      numeric parameter to ``'positive'`` or ``'non-negative'``: every
      such parameter must be a finite real number within its bound, or
      None where its default is None.  They are checked, and stored as
      ``float``, on construction and on every :meth:`set`;
    - ``system_quantities``: what of the atoms the results depend on
      (names as in :func:`exact_system_changes`);
    - ``calculate``, summing pair terms with :meth:`scatter_pairs` and
      :meth:`split_pair_energies`, and storing them with
      :meth:`store_results`.

    It may override ``_check_relations`` (checks between parameters)
    and ``_forget`` (drop caches that depend on the parameters).

    For the reversible adjoint it may declare
    :attr:`differentiable_parameters` and implement
    ``hessian_vector_product(atoms, v_nc)`` and
    ``_force_parameter_derivative(atoms, name)``; the base class turns
    them into the protocol the adjoint calls once per kick,
    :meth:`vector_jacobian_product`, with :meth:`parameter_values` and
    :meth:`set_parameter_values`.
    """

    #: Numeric parameter -> ``'positive'`` or ``'non-negative'``.
    parameter_bounds: dict = {}
    #: What of the atoms the results depend on, compared bit for bit.
    system_quantities = ('positions', 'numbers')
    nolabel = True
    #: Parameters the forces can be differentiated by (scalars, all of
    #: them numeric entries of ``parameters``).
    differentiable_parameters: tuple = ()

    #: The forces depend on the atoms alone.  Every subclass sums its terms
    #: in a fixed order and keeps no state that changes a bit of them; one
    #: that cannot promise this must set it to False, and
    #: ReversibleVerlet then probes it.
    forces_are_pure = True

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._check_parameters()
        self._forget()

    def set(self, **kwargs):
        """Change parameters (``name=value``): checks them and drops cached
        results.  Returns the changed parameters (dict)."""
        before = dict(self.parameters)
        changed = super().set(**kwargs)
        if changed:
            try:
                self._check_parameters()
            except (TypeError, ValueError):
                # Refused: the calculator keeps the parameters it had.
                self.parameters.clear()
                self.parameters.update(before)
                raise
            self._forget()
            # ASE's set keeps the results: they would be the old
            # parameters' at positions check_state finds unchanged.
            self.reset()
        return changed

    def _check_parameters(self):
        p = self.parameters
        defaults = self.default_parameters
        for name, bound in self.parameter_bounds.items():
            given = p[name]
            if given is None and defaults.get(name) is None:
                continue
            try:
                value = float(given)
            except (TypeError, ValueError):
                raise TypeError(f'{name} must be a number, got '
                                f'{given!r}') from None
            if not (math.isfinite(value)
                    and (value > 0 if bound == 'positive' else value >= 0)):
                raise ValueError(f'{name} must be a finite, {bound} number, '
                                 f'got {given!r}')
            p[name] = value
        self._check_relations()

    def _check_relations(self):
        """Raise ValueError if the (single, valid) parameters do not fit
        together."""

    def _forget(self):
        """Drop whatever is cached for the current parameters."""

    # -- ASE calculator interface ---------------------------------------

    def check_state(self, atoms, tol=1e-15):
        """What changed since the last calculation, compared exactly.

        A list of names from :attr:`system_quantities`; ``tol`` is ignored
        (ASE's default would treat moves below 1e-15 Å as none).
        """
        return exact_system_changes(self.atoms, atoms,
                                    self.system_quantities)

    def store_results(self, energy, energies_n, f_nc):
        """``energy`` (= ``free_energy``, eV), ``energies`` ``[n_atoms]``
        (eV) and ``forces`` ``[n_atoms, 3]`` (eV/Å) into ``results``."""
        self.results['energy'] = self.results['free_energy'] = energy
        self.results['energies'] = energies_n
        self.results['forces'] = f_nc

    # -- derivatives (the reversible adjoint's protocol) ------------------

    def checked_parameter_names(self, names):
        """``names`` (a str or a sequence) as a tuple, ValueError naming
        the available ones if any is not differentiable."""
        names = (names,) if isinstance(names, str) else tuple(names)
        unknown = [n for n in names if n not in self.differentiable_parameters]
        if unknown:
            raise ValueError(
                f'{type(self).__name__} cannot differentiate its forces by '
                f'{unknown}; available: {list(self.differentiable_parameters)}')
        return names

    def parameter_values(self, names=None):
        """``{name: value}`` (floats) of the differentiable parameters (all
        of them, or ``names``)."""
        names = self.differentiable_parameters if names is None \
            else self.checked_parameter_names(names)
        return {name: float(self.parameters[name]) for name in names}

    def set_parameter_values(self, values):
        """Set differentiable parameters from ``{name: value}`` (through
        :meth:`set`, so bounds are checked and the change is seen by the
        integrators, which move their anchor of reversal)."""
        values = dict(values)
        self.checked_parameter_names(tuple(values))
        converted = {}
        for name, value in values.items():
            array = np.asarray(value, dtype=float)
            if array.shape != ():
                raise ValueError(f'{name} is a scalar; got shape '
                                 f'{array.shape}')
            converted[name] = float(array)
        return self.set(**converted)

    def force_parameter_derivative(self, atoms, name):
        """``dF/d(name)`` ``[n_atoms, 3]`` at the atoms' positions (eV/Å
        per unit of the parameter)."""
        self.checked_parameter_names((name,))
        return self._force_parameter_derivative(atoms, name)

    def _force_parameter_derivative(self, atoms, name):
        raise NotImplementedError

    def vector_jacobian_product(self, atoms, v_nc, parameters=()):
        """``((dF/dx)^T v, {name: (dF/dtheta)^T v})`` at the atoms'
        positions: what the adjoint of a kick needs, in one call.

        ``v_nc`` is ``[n_atoms, 3]``; the first result too (eV/Å² x unit
        of ``v``); each parameter's is a float (eV/Å per unit of the
        parameter x unit of ``v``).  ``dF/dx = -H``, the Hessian of the
        energy, which is symmetric, so the first is ``-H v``.  Sums are
        in a fixed order: the same bits on every CPU.
        """
        v_nc = self.as_vector(atoms, v_nc)
        names = self.checked_parameter_names(parameters)
        hv_nc = self.hessian_vector_product(atoms, v_nc)
        dx_nc = np.negative(hv_nc, out=hv_nc)
        return dx_nc, {name: dot(self._force_parameter_derivative(atoms, name),
                                 v_nc) for name in names}

    # -- order-fixed sums -------------------------------------------------

    @staticmethod
    def scatter_pairs(t_pc, i_p, j_p, n):
        """``[n, 3]``: ``+t`` onto each pair's atom ``i``, ``-t`` onto ``j``.

        ``t_pc`` is ``[n_pairs, 3]``, ``i_p`` and ``j_p`` are ``[n_pairs]``
        atom indices.  :func:`numpy.bincount` adds each atom's terms in
        pair order, starting from zero, so the sums are the same bits
        whenever the terms and their order are.
        """
        out_nc = np.empty((n, 3))
        for c in range(3):
            out_nc[:, c] = (np.bincount(i_p, t_pc[:, c], minlength=n)
                            - np.bincount(j_p, t_pc[:, c], minlength=n))
        return out_nc

    @staticmethod
    def split_pair_energies(u_p, i_p, j_p, n):
        """``[n]``: each pair's energy ``u_p`` split equally between its two
        atoms, summed in pair order as in :meth:`scatter_pairs`."""
        return 0.5 * (np.bincount(i_p, u_p, minlength=n)
                      + np.bincount(j_p, u_p, minlength=n))

    @staticmethod
    def as_vector(atoms, v_nc):
        """``v_nc`` as a float ``[n_atoms, 3]`` array; ValueError if it has
        another shape (for ``hessian_vector_product``)."""
        v_nc = np.asarray(v_nc, dtype=float)
        if v_nc.shape != (len(atoms), 3):
            raise ValueError(f'v_nc must have shape ({len(atoms)}, 3), got '
                             f'{v_nc.shape}')
        return v_nc
