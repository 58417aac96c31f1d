"""Checks of plain numeric arguments, shared by every room that takes
them (the dynamics, the force providers, the adjoint): no ASE here."""

from __future__ import annotations

import math


def checked_positive(value, name, unit):
    """``value`` as a positive, finite float, else TypeError (not a
    number) or ValueError; ``name`` and ``unit`` for the message, which
    quotes the value as passed."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f'{name} must be a number ({unit}), got '
                        f'{value!r}') from None
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f'{name} must be positive and finite ({unit}), got '
                         f'{value!r}')
    return number
