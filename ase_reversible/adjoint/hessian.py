"""Hessian-vector products for the adjoint of a kick.

The adjoint of a kick ``p += c h F(x)`` adds ``c h (dF/dx)^T a_p`` to the
position adjoint.  For conservative forces ``dF/dx = -H``, with ``H`` the
(symmetric) Hessian of the potential energy, so one product ``H v`` per
kick is what the adjoint needs.  Two ways to get it:

:class:`AnalyticHVP`
    From the calculator, exact: ``calc.hessian_vector_product(atoms, v)``
    (this package's :class:`~ase_reversible.calculators.lennardjones.LennardJones` and
    :class:`~ase_reversible.calculators.chain.PendulumChain` have it).

:class:`FiniteDifferenceHVP`
    From any calculator, by a central difference of the forces along
    ``v``: two force calls.

Any callable ``hvp(atoms, v_nc) -> [n_atoms, 3]`` returning ``H v`` in
eV/Å² at the atoms' current positions can be passed instead
(``ReversibleVerlet.backpropagate(..., hvp=...)``).  It may move the atoms
but must put the positions back bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..core.arguments import checked_positive

#: Largest displacement of any atom in a finite-difference product, Å.
#: The central difference errs by ~ ``step**2 |F'''| / 6`` (truncation) plus
#: ~ (force rounding and noise) / step (cancellation).  Measured against
#: exact products (docs/adjoint.md): 4e-8 relative at 1e-4 Å, 4e-10 at
#: 1e-5 Å, 1e-9 at 3e-6 Å for argon.  A small step also makes it unlikely
#: that the two points straddle a cut-off where a calculator's forces
#: jump (EMT).
DEFAULT_FD_STEP = 1e-5


class AnalyticHVP:
    """Exact products from ``calc.hessian_vector_product(atoms, v_nc)``."""

    name = 'analytic'
    #: Force calls per product.
    force_calls = 0

    def __call__(self, atoms, v_nc):
        """``H v`` ``[n_atoms, 3]`` at the atoms' positions, eV/Å² x (unit
        of ``v_nc``); ``v_nc`` is ``[n_atoms, 3]``."""
        return atoms.calc.hessian_vector_product(atoms, v_nc)


class FiniteDifferenceHVP:
    """``H v ~ -(F(x + e v) - F(x - e v)) / (2 e)``, two force calls.

    Parameters
    ----------
    step : float
        Å: ``e`` is chosen so that the atom moved furthest moves by
        ``step``.  The error is measured in docs/adjoint.md and bounded in
        the tests: below 1e-8 relative for argon (Lennard-Jones) and
        1e-7 for copper (asap3 EMT) at the default.
    """

    name = 'finite-difference'
    force_calls = 2

    def __init__(self, step: float = DEFAULT_FD_STEP):
        self.step = checked_positive(step, 'The finite-difference step', 'Å')

    def __call__(self, atoms, v_nc):
        """``H v`` ``[n_atoms, 3]`` at the atoms' positions, eV/Å² x (unit
        of ``v_nc``); ``v_nc`` is ``[n_atoms, 3]``.

        Moves the atoms to ``x +- e v`` for two force calls and puts the
        positions back bit for bit.
        """
        scale = float(np.abs(v_nc).max(initial=0.0))
        if scale == 0.0:
            return np.zeros_like(v_nc)
        e = self.step / scale
        x_nc = atoms.positions.copy()
        try:
            atoms.positions = x_nc + e * v_nc
            f_plus_nc = atoms.get_forces(apply_constraint=False)
            atoms.positions = x_nc - e * v_nc
            f_minus_nc = atoms.get_forces(apply_constraint=False)
        finally:
            atoms.positions = x_nc
        return (f_minus_nc - f_plus_nc) / (2 * e)
