"""Symmetric compositions: higher-order schemes from the exact Verlet step.

A composition runs the second-order step ``S`` with a palindrome of
fractions of the time step, ``S(g_1 h) S(g_2 h) ... S(g_s h)`` with
``g_i = g_{s+1-i}`` and ``sum(g) = 1``.  For suitable fractions the
result is of order 4, 6, 8 or 10 (Yoshida 1990; Suzuki 1990; Kahan & Li,
Math. Comp. 66 (1997) 1089).  Each stage is made of the same exact drift
and kick sub-steps as ``S``, and the whole sequence stays a palindrome, so
a composed step run with ``-h`` is still its exact inverse.

Adjacent sub-steps of the same kind are merged into one: kick-drift-kick
stages share their kicks (``K(g_i/2) K(g_{i+1}/2)`` becomes
``K((g_i + g_{i+1})/2)``), so an ``s``-stage composition needs ``s`` force
calls per step, as many as ``s`` Verlet steps.

The fractions below are the published values: the triple jump in closed
form, the others as tabulated (to 20 digits) by Kahan & Li, as REBOUND's
JANUS integrator uses them (Rein & Tamayo, MNRAS 473 (2018) 3351).
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Composition(NamedTuple):
    """A palindrome of step fractions.

    Attributes
    ----------
    name : str
        A key of :data:`COMPOSITIONS`, or ``'custom'``.
    order : int
        Order of the composed method when ``S`` is of order 2.
    fractions : tuple of float
        All ``s`` fractions ``g_i`` of the time step, a palindrome.
    """

    name: str
    order: int
    fractions: tuple

    @property
    def stages(self) -> int:
        """Number of second-order steps, and of force calls, per step."""
        return len(self.fractions)


def _mirror(first_half):
    """The full palindrome from its first ``(s + 1) // 2`` entries."""
    head = tuple(float(g) for g in first_half)
    return head + head[-2::-1]


# 2.0 ** (1.0 / 3.0) and 4.0 ** (1.0 / 3.0), written out: ``**`` calls the
# platform's libm, which need not round them the same everywhere, and every
# kick's time step is made from them.  These are the correctly rounded
# values (checked with 60-digit decimal arithmetic), the bits ``**`` gave
# on the development machine, so no dynamics changed.
_CBRT2 = 1.2599210498948732
_SUZUKI_P = 1.0 / (4.0 - 1.5874010519681994)

#: The built-in compositions, by name.
#:
#: :meta hide-value:
COMPOSITIONS = {c.name: c for c in (
    Composition('verlet', 2, (1.0,)),
    # Yoshida's and Suzuki's triple jump: the cheapest order 4.
    Composition('triple-jump', 4, _mirror(
        (1.0 / (2.0 - _CBRT2), -_CBRT2 / (2.0 - _CBRT2)))),
    # Suzuki's five-stage fractal: smaller error for its cost.
    Composition('suzuki-5', 4, _mirror((_SUZUKI_P, _SUZUKI_P,
                                        1.0 - 4.0 * _SUZUKI_P))),
    Composition('kahan-li-9', 6, _mirror((
        0.39216144400731413928, 0.33259913678935943860,
        -0.70624617255763935981, 0.082213596293550800230,
        0.79854399093482996340))),
    Composition('kahan-li-15', 8, _mirror((
        0.74167036435061295345, -0.40910082580003159400,
        0.19075471029623837995, -0.57386247111608226666,
        0.29906418130365592384, 0.33462491824529818378,
        0.31529309239676659663, -0.79688793935291635402))),
    Composition('kahan-li-33', 10, _mirror((
        0.12313526870982994083, 0.77644981696937310520,
        0.14905490079567045613, -0.17250761219393744420,
        -0.54871240818800177942, 0.14289765421841842100,
        -0.31419193263986861997, 0.12670943739561041022,
        0.17444734584181312998, 0.44318544665428572929,
        -0.81948900568299084419, 0.13382545738489583020,
        0.64509023524410605020, -0.71936337169922060719,
        0.20951381813463649682, -0.26828113140636051966,
        0.83647216092348048955))),
)}

#: The composition used for ``order=k``.
DEFAULT_FOR_ORDER = {2: 'verlet', 4: 'suzuki-5', 6: 'kahan-li-9',
                     8: 'kahan-li-15', 10: 'kahan-li-33'}


def composition_for(order=2, composition=None) -> Composition:
    """The composition selected by ``order`` and optionally ``composition``.

    Parameters
    ----------
    order : int
        2, 4, 6, 8 or 10.
    composition : str or sequence of float, optional
        A name from :data:`COMPOSITIONS` of that order, or custom fractions
        (a palindrome summing to 1; its order is taken on trust).

    Returns
    -------
    Composition
        Raises ValueError for an unknown order or name, a name of another
        order, or fractions that are not a palindrome summing to 1.
    """
    if isinstance(order, bool) or not isinstance(order, int) \
            or order not in DEFAULT_FOR_ORDER:
        raise ValueError(f'order must be one of {tuple(DEFAULT_FOR_ORDER)}, '
                         f'got {order!r}')
    if composition is None:
        return COMPOSITIONS[DEFAULT_FOR_ORDER[order]]
    if isinstance(composition, str):
        known = COMPOSITIONS.get(composition)
        if known is None:
            raise ValueError(f'unknown composition {composition!r}; choose '
                             f'one of {tuple(COMPOSITIONS)} or give the '
                             'fractions')
        if known.order != order:
            raise ValueError(f'composition {composition!r} is of order '
                             f'{known.order}; pass order={known.order}')
        return known
    fractions = tuple(float(g) for g in composition)
    if not fractions or not all(math.isfinite(g) for g in fractions):
        raise ValueError('composition fractions must be finite numbers')
    if fractions != fractions[::-1]:
        raise ValueError('composition fractions must read the same '
                         'backwards (bit for bit): only a palindrome is '
                         'undone exactly by the step with -h')
    if abs(math.fsum(fractions) - 1.0) > 1e-12:
        raise ValueError(f'composition fractions must sum to 1, got '
                         f'{math.fsum(fractions)!r}')
    return Composition('custom', order, fractions)
