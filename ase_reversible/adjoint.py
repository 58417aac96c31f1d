"""The reversible adjoint: gradients through a run by retracing it exactly.

Reverse-mode differentiation of a run needs the states of the forward run
in reverse order.  Usually they are stored (memory proportional to the
number of steps) or recomputed from checkpoints.  ReversibleVerlet instead
runs back: every state it meets on the way is bitwise the forward one, so
the adjoint is integrated along the exact forward path with memory that
does not depend on the number of steps (J. Stam, "An Exact Bitwise
Reversible Integrator", section "Application: Reversible Adjoint", eq.
adjPosVerlet).

Each sub-step of the forward run is linear in the variable it updates;
with ``P`` the (orthogonal) constraint projection, ``m`` the masses, ``H``
the Hessian of the potential energy and ``a_x``, ``a_p`` the adjoints
(``dL/dx``, ``dL/dp``) ``[n_atoms, 3]``, its adjoint is::

    drift  x += c h P p / m     ->   a_p += c h P a_x / m
    kick   p += c h P F(x)      ->   a_x -= c h H(x) P a_p
                                     a_theta += c h (dF/dtheta)^T P a_p

applied in the reverse order of the forward sub-steps, each at the
positions that sub-step saw.  Rounding is not differentiated: the
gradient is that of the float-valued scheme, evaluated on the exact path,
so the only error is the adjoint integration's own floating point (and
that of the Hessian-vector products, see :mod:`ase_reversible.hessian`).

Kicks with no drift between them act at the same positions on the same
``a_p``; their products are merged into one.  The kick-drift-kick scheme
thus needs one product per step (``steps + 1`` for a retrace, the first
kick of the run included), the drift-kick-drift scheme one per kick.

Momenta that the constraints hold (a fixed atom's) are not free: the
constructor projects them, and no step changes them.  The momentum
gradient returned is therefore projected too, so an optimiser sees no
direction it cannot move in.  Positions of fixed atoms stay in the
position gradient: where a fixed atom is pinned changes the forces on the
others.
"""

from __future__ import annotations

import numpy as np

from .hessian import hvp_for


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
    """

    def __new__(cls, positions, momenta, parameters=None,
                hessian_vector_products=0):
        self = super().__new__(cls, (positions, momenta))
        self.parameters = dict(parameters or {})
        self.hessian_vector_products = hessian_vector_products
        return self

    @property
    def positions(self):
        """dL/d(positions) ``[n_atoms, 3]``, (loss unit) / Å."""
        return self[0]

    @property
    def momenta(self):
        """dL/d(momenta) ``[n_atoms, 3]``, (loss unit) / (amu Å / ASE time)."""
        return self[1]


class Adjoint:
    """The adjoint state carried back through a retrace.

    Parameters
    ----------
    atoms : ase.Atoms
        The atoms being retraced (positions, calculator).
    grad_positions, grad_momenta : array_like ``[n_atoms, 3]`` or None
        ``dL/dx`` and ``dL/dp`` at the state the retrace starts from; None
        means zero.
    masses_n1 : numpy.ndarray ``[n_atoms, 1]``
        amu.
    project : callable
        In-place constraint projection of an ``[n_atoms, 3]`` array.
    hvp : str or callable
        See :func:`ase_reversible.hessian.hvp_for`.
    parameters : sequence of str
        Potential parameters to differentiate; the calculator must list
        them in ``differentiable_parameters`` and provide
        ``force_parameter_derivative(atoms, name)``.

    Raises ValueError on bad input, before anything is computed.
    """

    def __init__(self, atoms, grad_positions, grad_momenta, masses_n1,
                 project, hvp='auto', parameters=()):
        n = len(atoms)
        self.ax_nc = _gradient(grad_positions, n, 'grad_positions')
        self.ap_nc = _gradient(grad_momenta, n, 'grad_momenta')
        self._m_n1 = masses_n1
        self._project = project
        self._hvp = hvp_for(atoms.calc, hvp)
        self.parameters = _parameters(atoms.calc, parameters)
        self.grad_parameters = {name: 0.0 for name in self.parameters}
        self.products = 0
        self._w_nc = np.empty((n, 3))
        self._pending = 0.0  # sum of c h over kicks not yet applied

    def kick(self, ch):
        """The adjoint of a forward kick ``p += ch P F(x)``, at x.

        ``ch``: the kick's coefficient times the time step, ASE time units.
        """
        # Deferred: the next drift or the end applies it, merged with any
        # other kick at these positions.
        self._pending += ch

    def drift(self, ch, atoms):
        """The adjoint of a forward drift ``x += ch P p / m``.

        ``ch`` in ASE time units.  Call before undoing that drift: pending
        kicks act at the positions the drift leads to.
        """
        self.flush(atoms)
        w_nc = np.divide(self.ax_nc, self._m_n1, out=self._w_nc)
        self._project(w_nc)
        w_nc *= ch
        self.ap_nc += w_nc

    def flush(self, atoms):
        """Apply the pending kicks at the atoms' current positions."""
        ch, self._pending = self._pending, 0.0
        if ch == 0.0:
            return
        w_nc = self._w_nc
        w_nc[:] = self.ap_nc
        self._project(w_nc)
        if not w_nc.any():
            return  # H 0 = 0 (a loss on positions only starts this way)
        # A copy: a user's product may keep or modify its argument.
        hv_nc = np.asarray(self._hvp(atoms, w_nc.copy()), dtype=float)
        if hv_nc.shape != w_nc.shape:
            raise ValueError(f'The Hessian-vector product has shape '
                             f'{hv_nc.shape}, expected {w_nc.shape}')
        self.products += 1
        self.ax_nc -= ch * hv_nc
        for name in self.parameters:
            df_nc = atoms.calc.force_parameter_derivative(atoms, name)
            self.grad_parameters[name] += ch * float(np.vdot(df_nc, w_nc))

    def result(self):
        """The gradients at the current state, as :class:`Gradients`.

        Copies of ``dL/dx`` and of the projected ``dL/dp``, each
        ``[n_atoms, 3]``, with the parameter gradients and the number of
        products.
        """
        ap_nc = self.ap_nc.copy()
        self._project(ap_nc)
        return Gradients(self.ax_nc.copy(), ap_nc, self.grad_parameters,
                         self.products)


def _gradient(value, n, name):
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


def _parameters(calc, names):
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
