"""The one product the adjoint of a kick needs, from whatever offers it.

The adjoint of a kick ``p += c h F(x)`` pulls the momentum cotangent ``w``
(already projected) back into the positions and the potential's
parameters::

    a_x     += c h (dF/dx)^T w
    a_theta += c h (dF/dtheta)^T w

Both are one vector-Jacobian product of the forces.  Where it comes from,
in the order ``hvp='auto'`` tries:

:class:`CalculatorProduct`
    ``calc.vector_jacobian_product(atoms, w, parameters)``: one call for
    both parts (this package's calculators, and
    ``ase_reversible.torch.TorchCalculator`` with one double-backward
    pass for any number of network weights).
:class:`HessianProduct`
    ``dx = -H w`` from a Hessian-vector product (the calculator's
    ``hessian_vector_product``, a central finite difference of the forces,
    or the user's callable), and each parameter's part from
    ``calc.force_parameter_derivative(atoms, name)``, one full ``[n_atoms,
    3]`` array per parameter: fine for a few parameters, not for a
    network's thousands.

A product is called as ``product(atoms, w_nc) -> (dx_nc, {name: dtheta})``
and counts its calls.
"""

from __future__ import annotations

import numpy as np

from ..core.portable import dot
from .hessian import AnalyticHVP, FiniteDifferenceHVP

#: The named sources of products (besides a callable).
HVP_CHOICES = ('auto', 'analytic', 'finite-difference')


class CalculatorProduct:
    """Both parts from ``calc.vector_jacobian_product`` in one call.

    Parameters
    ----------
    parameters : tuple of str
        Names passed through to the calculator.
    """

    def __init__(self, parameters=()):
        self.parameters = tuple(parameters)

    def __call__(self, atoms, w_nc):
        """``((dF/dx)^T w, {name: (dF/dtheta)^T w})`` at the atoms'
        positions; ``w_nc`` is ``[n_atoms, 3]``."""
        dx_nc, dtheta = atoms.calc.vector_jacobian_product(
            atoms, w_nc, self.parameters)
        dx_nc = np.asarray(dx_nc, dtype=float)
        missing = [n for n in self.parameters if n not in dtheta]
        if missing:
            raise ValueError(
                f'{type(atoms.calc).__name__}.vector_jacobian_product '
                f'returned no derivative for {missing}')
        return dx_nc, dtheta


class HessianProduct:
    """``dx = -H w`` from ``hvp(atoms, w)``, parameters from
    ``calc.force_parameter_derivative``.

    Parameters
    ----------
    hvp : callable
        ``hvp(atoms, v_nc) -> H v_nc`` ``[n_atoms, 3]``, eV/Å² x unit of
        ``v`` (:mod:`.hessian`, or the user's).
    parameters : tuple of str
        Names for ``calc.force_parameter_derivative(atoms, name)``.
    """

    def __init__(self, hvp, parameters=()):
        self.hvp = hvp
        self.parameters = tuple(parameters)

    def __call__(self, atoms, w_nc):
        """``(-H w, {name: (dF/dtheta)^T w})`` at the atoms' positions;
        ``w_nc`` is ``[n_atoms, 3]``."""
        # A copy: a user's product may keep or modify its argument.  The
        # kick checks the shape of what comes back.
        hv_nc = np.asarray(self.hvp(atoms, w_nc.copy()), dtype=float)
        dtheta = {name: dot(atoms.calc.force_parameter_derivative(atoms,
                                                                  name),
                            w_nc)
                  for name in self.parameters}
        return -hv_nc, dtheta


def product_for(calc, hvp='auto', parameters=()):
    """The product the kicks' adjoint will call, for ``calc``.

    ``hvp``: ``'auto'`` (the calculator's ``vector_jacobian_product`` if
    it has one, else its ``hessian_vector_product``, else two force calls
    per product), ``'analytic'`` (the calculator's own, either kind),
    ``'finite-difference'``, or a callable ``hvp(atoms, v_nc) -> H v``.
    ``parameters``: names already checked by :func:`checked_parameters`.
    """
    if callable(hvp):
        return HessianProduct(hvp, parameters)
    if hvp not in HVP_CHOICES:
        raise ValueError(f'hvp must be one of {HVP_CHOICES} or a callable '
                         f'hvp(atoms, v_nc) returning H v, got {hvp!r}')
    vjp = callable(getattr(calc, 'vector_jacobian_product', None))
    analytic = callable(getattr(calc, 'hessian_vector_product', None))
    if hvp == 'analytic' and not (vjp or analytic):
        raise ValueError(
            f'{type(calc).__name__} has neither vector_jacobian_product nor '
            "hessian_vector_product; use hvp='finite-difference' (two force "
            'calls per product) or pass your own hvp(atoms, v_nc).')
    if hvp == 'finite-difference':
        if parameters:
            raise ValueError(
                'Finite differences give the products for the positions '
                'only; parameter gradients need the calculator\'s '
                "vector_jacobian_product (use hvp='auto').")
        return HessianProduct(FiniteDifferenceHVP(), ())
    if vjp:
        return CalculatorProduct(parameters)
    if analytic:
        return HessianProduct(AnalyticHVP(), parameters)
    return HessianProduct(FiniteDifferenceHVP(), parameters)


def checked_parameters(calc, names):
    """``names`` as a tuple, refused unless ``calc`` can differentiate its
    forces with respect to each (through ``vector_jacobian_product``, or
    the older ``force_parameter_derivative``)."""
    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    if not names:
        return names
    available = tuple(getattr(calc, 'differentiable_parameters', ()))
    unknown = [n for n in names if n not in available]
    able = (callable(getattr(calc, 'vector_jacobian_product', None))
            or callable(getattr(calc, 'force_parameter_derivative', None)))
    if unknown or not able:
        raise ValueError(
            f'{type(calc).__name__} cannot differentiate its forces with '
            f'respect to {unknown or list(names)}; it offers '
            f'{list(available) or "no parameters"} (a calculator provides '
            'them with differentiable_parameters and '
            'vector_jacobian_product(atoms, v, parameters)).')
    return names


def zero_gradients(calc, names):
    """``{name: 0}`` shaped like each parameter's value (from
    ``calc.parameter_values`` where the calculator has it; 0.0 else)."""
    values = {}
    if names and callable(getattr(calc, 'parameter_values', None)):
        values = calc.parameter_values(names)
    return {name: (np.zeros_like(np.asarray(values[name], dtype=float))
                   if name in values and np.ndim(values[name]) else 0.0)
            for name in names}
