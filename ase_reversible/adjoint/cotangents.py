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
        ``dL/dtheta`` for each potential parameter asked for.
    hessian_vector_products : int
        Products computed during the retrace.
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
        self.hessian_vector_products = hessian_vector_products
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
    sub-steps' adjoint rules share: the Hessian-vector product, the
    potential parameters asked for and their gradients, and adjoint
    updates deferred so that neighbours can be merged.

    Parameters
    ----------
    arrays : dict of str to numpy.ndarray
        The starting cotangents (float64, owned by this object).
    hvp : callable, optional
        ``hvp(atoms, v_nc) -> H v_nc`` (see :mod:`.hessian`).
    parameters : tuple of str
        Potential parameters to differentiate.
    """

    def __init__(self, arrays, hvp=None, parameters=()):
        super().__init__(arrays)
        self.hvp = hvp
        self.parameters = tuple(parameters)
        self.grad_parameters = {name: 0.0 for name in self.parameters}
        #: Hessian-vector products computed so far.
        self.products = 0
        self._pending = {}

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


def checked_parameters(calc, names):
    """``names`` as a tuple, refused unless ``calc`` can differentiate its
    forces with respect to each."""
    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    if not names:
        return names
    available = tuple(getattr(calc, 'differentiable_parameters', ()))
    unknown = [n for n in names if n not in available]
    if unknown or not callable(getattr(calc, 'force_parameter_derivative',
                                       None)):
        raise ValueError(
            f'{type(calc).__name__} cannot differentiate its forces with '
            f'respect to {unknown or list(names)}; it offers '
            f'{list(available) or "no parameters"} (a calculator provides '
            'them with differentiable_parameters and '
            'force_parameter_derivative(atoms, name)).')
    return names
