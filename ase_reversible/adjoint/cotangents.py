"""Cotangents (the adjoint state of a retrace) and the gradients returned.

Each exact variable has a cotangent ``dL/d(variable)`` of its own shape;
the sub-steps' adjoint rules update them (see :mod:`ase_reversible.adjoint`).
"""

from __future__ import annotations

import numpy as np



class Gradients(tuple):
    """``(dL/dpositions, dL/dmomenta)``, each ``[n_atoms, 3]``.

    Unpacks as a pair.  Units: eV/Å and eV / (amu Å / ASE time) for a loss
    in eV.

    Attributes
    ----------
    positions, momenta : numpy.ndarray
        The pair, by name.
    parameters : dict
        ``dL/dtheta`` for each potential parameter asked for, shaped like
        the parameter's value (a float for a scalar).
    products : int
        Vector-Jacobian (or Hessian-vector) products computed during the
        retrace; also ``hessian_vector_products``.
    thermostat : dict
        dL/d(variable) for a thermostat's own variables (empty for
        dynamics without any), at fixed positions and momenta: for
        :class:`~ase_reversible.ReversibleNose`, ``'s'`` and ``'pi'``.
        A loss on several states passes them on to the next segment's
        retrace (``backpropagate(..., carry=gradients)``).
    """

    def __new__(cls, positions, momenta, parameters=None,
                hessian_vector_products=0, thermostat=None):
        self = super().__new__(cls, (positions, momenta))
        self.parameters = dict(parameters or {})
        self.products = self.hessian_vector_products = \
            hessian_vector_products
        self.thermostat = dict(thermostat or {})
        return self

    @property
    def positions(self):
        """dL/d(positions) ``[n_atoms, 3]``, (loss unit) / Å."""
        return self[0]

    @property
    def momenta(self):
        """dL/d(momenta) ``[n_atoms, 3]``, (loss unit) / (amu Å / ASE time)."""
        return self[1]


class Cotangents(dict):
    """The adjoint state carried back through a retrace.

    A dict of ``dL/d(variable)`` arrays by variable name (``'position'``,
    ``'momentum'``, ...), each of the variable's shape, plus what the
    sub-steps' adjoint rules share: the vector-Jacobian product of the
    forces, the gradients of the potential parameters asked for, and
    adjoint updates deferred so that neighbours can be merged.

    Parameters
    ----------
    arrays : dict of str to numpy.ndarray
        The starting cotangents (float64, owned by this object).
    product : callable, optional
        ``product(atoms, w_nc) -> ((dF/dx)^T w, {name: (dF/dtheta)^T w})``
        (see :mod:`.products`).
    grad_parameters : dict, optional
        ``{name: zero}`` for each parameter to differentiate, shaped like
        it (:func:`.products.zero_gradients`).
    """

    def __init__(self, arrays, product=None, grad_parameters=None):
        super().__init__(arrays)
        self.product = product
        self.grad_parameters = dict(grad_parameters or {})
        #: Products computed so far.
        self.products = 0
        self._pending = {}

    def clear(self):
        """Zero every cotangent (the start of a truncation window: what
        came before does not reach the loss), keeping the parameters'."""
        self.flush()
        for array in self.values():
            array[...] = 0.0

    def defer(self, rule, ch):
        """Add ``ch`` to the pending coefficient of ``rule``.

        ``rule(cotangents, ch)`` is applied once, with the sum, at the next
        :meth:`flush`: adjoint kicks with no drift between them act at the
        same positions on the same momentum cotangent, so one
        Hessian-vector product serves them all.
        """
        self._pending[rule] = self._pending.get(rule, 0.0) + ch

    def flush(self):
        """Apply the deferred updates (before anything they read changes)."""
        pending, self._pending = self._pending, {}
        for rule, ch in pending.items():
            if ch != 0.0:
                rule(self, ch)


def checked_gradient(value, n, name):
    """``value`` as a float array ``[n, 3]`` (zeros for None), refused
    with a message naming ``name`` if it is not one."""
    if value is None:
        return np.zeros((n, 3))
    try:
        g_nc = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f'{name} must be an array of numbers of shape '
                        f'({n}, 3), got {type(value).__name__}') from None
    if g_nc.shape != (n, 3):
        raise ValueError(f'{name} must have shape ({n}, 3) (one row per '
                         f'atom), got {g_nc.shape}')
    if not np.all(np.isfinite(g_nc)):
        raise ValueError(f'{name} contains non-finite values')
    return g_nc
