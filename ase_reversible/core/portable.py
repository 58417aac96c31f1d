"""Float kernels that give the same bits on every CPU.

A run written on one machine may be continued, or run back, on another.
Every float that decides a bit of the exact state must then be the same
there.  IEEE 754 rounds ``+ - * /`` and ``sqrt`` correctly, so a fixed
sequence of them gives the same bits everywhere; what does not:

- numpy's ``exp``, ``log``, ``power`` (``x**6``, ``x**-1.5``), ``cbrt``
  and ``tanh`` run SIMD code chosen for the CPU at import time, and the
  scalar ``math`` functions and Python's ``**`` call the platform's libm;
- BLAS (``@``, ``np.dot``, ``np.vdot``, ``np.linalg``) picks kernels, and
  with them the order of its sums and its use of fused multiply-adds, by
  core type;
- a reduction whose order follows the SIMD vector width.

Measured with ``tests/machines.py`` (numpy 2.4, its AVX-512 and AVX2
dispatch switched off, another OpenBLAS core type): ``np.exp``,
``np.log``, ``x**6``, ``x**3``, ``x**-1.5``, ``np.cbrt``, ``np.tanh`` and
every BLAS product changed last bits; ``+ - * /``, ``sqrt``, ``np.sum``,
``np.bincount`` did not.  ``np.sum`` adds in a fixed pairwise order (eight
running sums, blocks of 128) and ``np.bincount`` in index order, whatever
the CPU, so both are used; integer powers are written as products and dot
products as elementwise products summed by these.
"""

from __future__ import annotations

import decimal

import numpy as np

#: 34 digits: a float64 rounded from such a result is the correctly
#: rounded value unless the exact one lies within 1e-34 (relative) of a
#: midpoint between two floats; deterministic in any case.
_CONTEXT = decimal.Context(prec=34)


def rowdot(a_pc, b_pc):
    """``[p]``: ``a . b`` of each row of two ``[p, 3]`` arrays, summed
    ``(x + y) + z``."""
    # One pass of products, then the columns added in place: the same
    # bits as three column products and 1.6x to 2.8x faster (1,500 to
    # 8,000 rows); 2.4x to 5.5x faster than einsum, whose bits differ
    # (best of 7 repeats, machine loaded at 3).
    ab_pc = a_pc * b_pc
    out_p = ab_pc[:, 0] + ab_pc[:, 1]
    out_p += ab_pc[:, 2]
    return out_p


def rowsquare(a_pc):
    """``[p]``: ``|a|**2`` of each row of a ``[p, 3]`` array."""
    return rowdot(a_pc, a_pc)


def dot(a, b) -> float:
    """``sum a * b`` over all elements of two arrays of one shape, in
    numpy's fixed pairwise order."""
    return float(np.sum(np.multiply(a, b)))


def rows_times_matrix(s_pc, m_cc):
    """``[p, 3]``: ``s @ m`` for a ``[3, 3]`` matrix, each element summed
    ``(x + y) + z``."""
    return (s_pc[:, 0:1] * m_cc[0] + s_pc[:, 1:2] * m_cc[1]) \
        + s_pc[:, 2:3] * m_cc[2]


def outer_sum(a_pc, b_pc):
    """``[3, 3]``: ``a.T @ b`` of two ``[p, 3]`` arrays, each element an
    ``np.sum`` over the rows."""
    out_cc = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out_cc[i, j] = np.sum(a_pc[:, i] * b_pc[:, j])
    return out_cc


def exp(x: float) -> float:
    """``e**x`` for a float ``x``, the float64 nearest to it (decimal
    arithmetic in software: no libm, the same bits everywhere).  For
    settings computed once per time step, not for arrays."""
    return float(_CONTEXT.exp(decimal.Decimal(float(x))))


def log(x: float) -> float:
    """``ln x`` for a positive float ``x``, as :func:`exp`."""
    return float(_CONTEXT.ln(decimal.Decimal(float(x))))
