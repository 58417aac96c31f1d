"""The retrace that integrates the adjoint: the work of
:meth:`~ase_reversible.md.base.ReversibleDynamics.backpropagate` once its
arguments are checked and the changes around the run taken.

The dynamics hands in its engine, its system and its hooks (the change of
variables between what the atoms show and the exact variables); nothing
here knows a particular dynamics.
"""

from __future__ import annotations

import numpy as np

from .cotangents import Cotangents, Gradients, checked_gradient
from .products import checked_parameters, product_for, zero_gradients
from .schedule import LossSchedule


def retrace_gradients(engine, system, atoms, steps, grad_positions,
                      grad_momenta, *, hvp, parameters, carry, loss, every,
                      window, cotangents_of, loss_cotangents, gradients_of,
                      committed):
    """Retrace ``steps`` steps of ``engine`` integrating the adjoint, and
    return the :class:`Gradients` at the state reached.

    Parameters
    ----------
    engine : ase_reversible.core.engine.Engine
        The dynamics' engine; its anchor bounds how far it can retrace.
    system
        The dynamics' system: ``show_momenta()``, ``centre`` (FixCom's
        balance, or None) and ``project`` (the constraint projection).
    atoms : ase.Atoms
    steps : int
        Steps to retrace, >= 0 (checked).
    grad_positions, grad_momenta : array_like ``[n_atoms, 3]`` or None
        dL/dx ((loss unit) / Å) and dL/dp ((loss unit) / (amu Å / ASE
        time)) at the present state.
    hvp, parameters, carry, loss, every, window
        As for ``backpropagate`` (``every`` and ``window`` checked).
    cotangents_of : callable
        ``(ax_nc, ap_nc, carry) -> {variable: cotangent}``: the dynamics'
        cotangents for gradients on the shown positions and momenta.
    loss_cotangents : callable
        ``(ax_nc, ap_nc or None) -> {variable: cotangent}``: what a loss
        at the present state adds.
    gradients_of : callable
        ``cotangents -> (dL/dx, dL/dp, thermostat)`` on the shown
        positions and momenta.
    committed : callable
        Shows the state reached on the atoms with its restart record; run
        even if the retrace fails.
    """
    available = engine.steps_since_anchor
    if steps > available:
        raise ValueError(
            f'Cannot retrace {steps} steps: only {available} were taken '
            'in this direction since the anchor of reversal (the '
            'constructor, or the last change taken: an edit of the '
            'atoms, the calculator, the constraints, the cell, or the '
            'size of dt). Steps before it ran under other dynamics. '
            f'Call backpropagate with at most {available} steps.')
    n = len(atoms)
    if carry not in (None, False) and not isinstance(carry, Gradients):
        raise TypeError('carry must be the Gradients the previous '
                        f'backpropagate returned (or False), got '
                        f'{type(carry).__name__}')
    if grad_positions is None and grad_momenta is None and loss is None:
        raise ValueError('Nothing to differentiate: give grad_positions '
                         'and/or grad_momenta (the loss\'s gradients at '
                         'the present state) or loss=.')
    ax_nc = checked_gradient(grad_positions, n, 'grad_positions')
    ap_nc = checked_gradient(grad_momenta, n, 'grad_momenta')
    names = checked_parameters(atoms.calc, parameters)
    cotangents = Cotangents(
        cotangents_of(ax_nc, ap_nc, carry),
        product=product_for(atoms.calc, hvp, names),
        grad_parameters=zero_gradients(atoms.calc, names))
    schedule = LossSchedule(steps, loss, every, window, system.show_momenta,
                            loss_cotangents, atoms)
    schedule.start(cotangents, bool(ax_nc.any() or ap_nc.any() or carry))
    try:
        engine.retrace(steps, cotangents, visit=schedule)
    finally:
        committed()
    ax_nc, ap_nc, thermostat = gradients_of(cotangents)
    if system.centre is not None:
        system.centre.pull_back(ap_nc)
    system.project(ap_nc)
    grads = {name: float(g) if np.ndim(g) == 0 else g
             for name, g in cotangents.grad_parameters.items()}
    return Gradients(ax_nc, ap_nc, grads, cotangents.products, thermostat)
