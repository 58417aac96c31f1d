"""The exact state of atoms, as the integrators hand it out."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class FixedPointState(NamedTuple):
    """Exact dynamical state.  Arrays are never modified in place.

    Attributes
    ----------
    ix_nc : int64 array [n_atoms, 3]
        Positions in units of ``Grid.position_quantum``.
    ip_nc : int64 array [n_atoms, 3]
        Momenta in units of ``Grid.momentum_quantum``.
    """

    ix_nc: np.ndarray
    ip_nc: np.ndarray
