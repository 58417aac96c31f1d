"""Gaussian noise that the way back can draw again, bit for bit.

A thermostat's random kicks must be subtracted exactly on the way back, so
they are a pure function of where they are used: the noise of step ``k``
is drawn from NumPy's Philox generator, a counter-based generator (J.
Salmon et al., "Parallel random numbers: as easy as 1, 2, 3", SC 2011),
keyed by the seed and the time step and started at counter ``k``.  Nothing
is stored: the way back starts the generator at the same counter.  Each
consumer of one key draws on its own :class:`Lane` (the counter's last
word), so no two of them ever read the same words.

Only the raw 64-bit words of a NumPy bit generator are promised to stay the
same across NumPy versions (NumPy's policy on stream compatibility), not
its Gaussian sampler, and a libm's ``log`` may differ between machines in
the last bit.  So the deviates are made here from the raw words, by
Marsaglia's polar method with a logarithm of basic operations only (``+ -
* /``, ``sqrt``, ``frexp``), which IEEE 754 rounds correctly everywhere: a
restart on another machine or NumPy draws the very same noise.
"""

from __future__ import annotations

import enum
import math
import struct

import numpy as np

_LN2 = 0.6931471805599453  # ln 2, the float nearest to it
_SQRT_HALF = 0.7071067811865476
#: 1 / (2j + 1) for the series of atanh, j = 1..8.
_ODD_RECIPROCALS = tuple(1.0 / (2 * j + 1) for j in range(8, 0, -1))
_UNIT = 2.0**-53


@enum.unique
class Lane(enum.IntEnum):
    """The last word of the Philox counter: one lane per consumer of a
    step's key, so that their words never overlap.  A new consumer takes a
    new lane; the values are part of every recorded run's bits."""

    #: The thermostats' Gaussian deviates (:class:`StepNoise`).
    NOISE = 0
    #: The reserve words below a scaling buffer's stacks
    #: (:class:`~ase_reversible.core.scaling.ScalingBuffer`).
    RESERVE = 1
    #: Bussi's normal and chi-squared draws (:class:`BussiDraws`).
    BUSSI = 2


def philox_stream(generator, key, index, lane):
    """Start ``generator`` (a ``numpy.random.Philox``) at counter
    ``[0, 0, index, lane]`` under ``key`` (two uint64, :func:`step_key`),
    with nothing buffered; returns it.  ``index`` is any int (also
    negative: taken modulo ``2**64``), ``lane`` a :class:`Lane`."""
    generator.state = {
        'bit_generator': 'Philox',
        'state': {'counter': np.array([0, 0, index % 2**64, int(lane)],
                                      dtype=np.uint64),
                  'key': key},
        'buffer': np.zeros(4, dtype=np.uint64), 'buffer_pos': 4,
        'has_uint32': 0, 'uinteger': 0}
    return generator


def portable_log(s):
    """``ln s`` for positive finite ``s`` (a float, or a float64 array), to
    about 1e-15 relative, with the same bits on every IEEE 754 machine and
    for a float as for the same value in an array: ``s = m 2**e`` with
    ``m`` in ``[sqrt(1/2), sqrt(2))``, then ``ln m = 2 atanh(f)``, ``f =
    (m - 1) / (m + 1)``, summed to ``f**17`` (``|f| < 0.172``)."""
    if isinstance(s, float):
        # Python floats for the few deviates of a Bussi step: numpy's
        # per-call overhead would cost more than the arithmetic.
        m, e = math.frexp(s)
        if m < _SQRT_HALF:
            m, e = 2.0 * m, e - 1
    else:
        m, e = np.frexp(s)
        low = m < _SQRT_HALF
        m = np.where(low, 2.0 * m, m)
        e = np.where(low, e - 1, e)
    f = (m - 1.0) / (m + 1.0)
    w = f * f
    # In place on an array (a new float otherwise): the same operations.
    series = _ODD_RECIPROCALS[0] * w
    series += _ODD_RECIPROCALS[1]
    for c in _ODD_RECIPROCALS[2:]:
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
        generator = philox_stream(self._generator, key, step, Lane.NOISE)
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


class BussiDraws:
    """The normal ``R`` and the chi-squared ``S`` of a step of Bussi's
    thermostat (:mod:`ase_reversible.md.bussi`), the same bits on every CPU
    and both ways.

    Python floats throughout: a handful of deviates a step, where numpy's
    per-call overhead would cost ten times the arithmetic (340 µs against
    about 25 µs a step, measured under load).  Each operation is an IEEE
    754 ``+ - * /`` or ``sqrt``, correctly rounded on every CPU, and the
    logarithm is :func:`portable_log` on a float.  Raw words come from
    NumPy's Philox keyed as the step's noise (:func:`step_key`) on
    :attr:`Lane.BUSSI`: the normals by Marsaglia's polar method
    (:func:`polar_normal`), ``S`` as ``2 Gamma((N_f - 1) / 2)`` by Marsaglia
    and Tsang's method (one normal and one uniform a candidate; accepted
    with probability above 0.95 for shapes of at least 1).

    Parameters
    ----------
    dof : int
        ``N_f``; ``S`` has ``N_f - 1`` degrees of freedom.
    """

    def __init__(self, dof):
        self.dof = int(dof)
        self._generator = np.random.Philox(key=[0, 0])
        shape = 0.5 * (self.dof - 1)
        self._d = shape - 1.0 / 3.0
        self._c = 1.0 / math.sqrt(9.0 * self._d) if shape >= 1 else None

    def __call__(self, key, step):
        """``(R, S)`` (floats) for step ``step`` under ``key``."""
        words = self._words(key, step)
        r = polar_normal(words)
        if self.dof <= 2:  # shapes 0 and 1/2: no squares, or one
            if self.dof < 2:
                return r, 0.0
            x = polar_normal(words)
            return r, x * x
        d, c = self._d, self._c
        while True:
            x = polar_normal(words)
            v = 1.0 + c * x
            if v <= 0.0:
                continue
            v = v * v * v
            u = ((next(words) >> 11) + 0.5) * _UNIT
            if portable_log(u) < 0.5 * x * x + d * (1.0 - v
                                                    + portable_log(v)):
                return r, 2.0 * d * v

    def _words(self, key, step):
        """The step's raw 64-bit words as Python ints, drawn 16 at a
        time."""
        generator = philox_stream(self._generator, key, step, Lane.BUSSI)
        while True:
            yield from generator.random_raw(16).tolist()


def polar_normal(words):
    """A standard normal (float) from ``words`` (an iterator of 64-bit
    ints) by Marsaglia's polar method, the second of the pair dropped: one
    state, no cache to roll back."""
    while True:
        u = (next(words) >> 11) * (2.0 * _UNIT) - 1.0
        v = (next(words) >> 11) * (2.0 * _UNIT) - 1.0
        s = u * u + v * v
        if 0.0 < s < 1.0:
            return u * math.sqrt(-2.0 * portable_log(s) / s)
