"""Gaussian noise that the way back can draw again, bit for bit.

A thermostat's random kicks must be subtracted exactly on the way back, so
they are a pure function of where they are used: the noise of step ``k``
is drawn from NumPy's Philox generator, a counter-based generator (J.
Salmon et al., "Parallel random numbers: as easy as 1, 2, 3", SC 2011),
keyed by the seed and the time step and started at counter ``k``.  Nothing
is stored: the way back starts the generator at the same counter.

Only the raw 64-bit words of a NumPy bit generator are promised to stay the
same across NumPy versions (NumPy's policy on stream compatibility), not
its Gaussian sampler, and a libm's ``log`` may differ between machines in
the last bit.  So the deviates are made here from the raw words, by
Marsaglia's polar method with a logarithm of basic operations only (``+ -
* /``, ``sqrt``, ``frexp``), which IEEE 754 rounds correctly everywhere: a
restart on another machine or NumPy draws the very same noise.
"""

from __future__ import annotations

import struct

import numpy as np

_LN2 = 0.6931471805599453  # ln 2, the float nearest to it
_SQRT_HALF = 0.7071067811865476
#: 1 / (2j + 1) for the series of atanh, j = 1..8.
_ODD_RECIPROCALS = tuple(1.0 / (2 * j + 1) for j in range(8, 0, -1))
_UNIT = 2.0**-53


def portable_log(s: np.ndarray) -> np.ndarray:
    """``ln s`` for positive finite ``s``, to about 1e-15 relative, with the
    same bits on every IEEE 754 machine: ``s = m 2**e`` with ``m`` in
    ``[sqrt(1/2), sqrt(2))``, then ``ln m = 2 atanh(f)``, ``f = (m - 1) / (m
    + 1)``, summed to ``f**17`` (``|f| < 0.172``)."""
    m, e = np.frexp(s)
    low = m < _SQRT_HALF
    m = np.where(low, 2.0 * m, m)
    e = np.where(low, e - 1, e)
    f = (m - 1.0) / (m + 1.0)
    w = f * f
    series = np.full_like(w, _ODD_RECIPROCALS[0])
    for c in _ODD_RECIPROCALS[1:]:
        series *= w
        series += c
    series *= w
    series += 1.0
    return e * _LN2 + 2.0 * f * series


def step_key(seed: int, dt: float) -> np.ndarray:
    """Philox key (two uint64) for ``seed`` and the time step's size."""
    bits = struct.unpack('<Q', struct.pack('<d', abs(float(dt))))[0]
    return np.array([int(seed) % 2**64, bits], dtype=np.uint64)


class StepNoise:
    """Standard normal deviates for each step, drawn anew on demand.

    Parameters
    ----------
    size : int
        Deviates per step (``3 n_atoms``).
    """

    def __init__(self, size: int):
        self.size = int(size)
        self._generator = np.random.Philox(key=[0, 0])
        self._pairs = (self.size + 1) // 2

    def normals(self, key: np.ndarray, step: int) -> np.ndarray:
        """float64 ``[size]``: the deviates of step ``step`` (any int, also
        negative) under ``key`` (:func:`step_key`)."""
        generator = self._generator
        generator.state = {
            'bit_generator': 'Philox',
            'state': {'counter': np.array([0, 0, step % 2**64, 0],
                                          dtype=np.uint64),
                      'key': key},
            'buffer': np.zeros(4, dtype=np.uint64), 'buffer_pos': 4,
            'has_uint32': 0, 'uinteger': 0}
        need, found = self._pairs, []
        while need > 0:
            # About 79% of pairs fall in the unit disc; draw a few more.
            draw = need + need // 3 + 8
            raw = generator.random_raw(2 * draw).reshape(2, draw)
            uv = (raw >> np.uint64(11)).astype(np.float64)
            uv *= 2.0 * _UNIT
            uv -= 1.0
            u, v = uv
            s = u * u + v * v
            inside = (s < 1.0) & (s > 0.0)
            u, v, s = u[inside][:need], v[inside][:need], s[inside][:need]
            factor = np.sqrt(-2.0 * portable_log(s) / s)
            found += [u * factor, v * factor]
            need -= len(s)
        return np.concatenate(found)[:self.size]
