"""Exact multiplication by any ratio ``n / 2**20``, above one as well as
below, with the digits kept: the information buffer of Bussi's rescaling
(:mod:`ase_reversible.md.bussi`), a sibling of
:mod:`ase_reversible.core.infobuffer` (whose docstring has the idea and
its sources)."""

from __future__ import annotations

import numpy as np

from .noise import Lane, philox_stream

#: A ratio is applied as ``n / 2**RATIO_BITS``.
RATIO_BITS = 20
_D = 1 << RATIO_BITS
_WORD_BITS = 16
_WORD = 1 << _WORD_BITS
#: The buffer's states lie in ``[_LOW, _HIGH)``; ``_LOW`` a multiple of
#: ``2**RATIO_BITS`` makes the bounds between moved and kept words exact
#: for every ratio (see :class:`ScalingBuffer`).
_LOW = _D
_HIGH = _LOW << _WORD_BITS
#: The ratios applied: ``alpha`` in ``[2**-16, 2**7)``.  One word moves
#: per step at most, which bounds the ratio to ``2**+-16``; ``n < 2**27``
#: keeps every product below ``2**63`` and a stored ratio in 32 bits.
N_MIN, N_MAX = 1 << (RATIO_BITS - _WORD_BITS), 1 << 27


class ScalingBuffer:
    """Exact multiplication of integer counts by ``n / 2**20`` for any
    ``n`` in ``[2**4, 2**27)``, the digits kept, one buffer a coordinate.

    As :class:`~ase_reversible.core.infobuffer.InformationBuffer` (its
    docstring has the idea and its sources), a coordinate's buffer is a
    range-coder state ``s`` and a stack of 16-bit words; here the same
    buffer serves every ratio, above one as well as below.  With
    ``d = 2**20``, one step maps ``(x, s)`` to ``(x', s')``:

    * pop an ``n``-ary digit ``a = s mod n`` from the state, form
      ``y = x n + a``, keep ``x' = y div d`` and push ``y mod d``:
      ``s' = (s div n) d + (y mod d)``, a bijection of ``(x, s)``;
    * before it, the state is brought where the result lands in
      ``[L, 2**16 L)`` (``L = d``): for ``n < d`` a state
      ``s >= 2**16 n`` first spills its low word onto the stack; for
      ``n > d`` a state ``s < n`` first takes a word from it.

    The way back splits ``s'`` into ``s div n`` and ``y mod d`` (``d`` is
    a power of two), rebuilds ``y = x' d + (y mod d)``, so ``x`` and
    ``s``; a state below ``L`` (``n < d``) or at or above ``2**16 L``
    (``n > d``) is one whose word moved, which is moved back.  Popping
    before pushing puts the digit below the product, so ``x'`` differs
    from ``n x / d`` by less than ``max(1, n / d)`` counts.  Pushing
    first, as ``InformationBuffer`` does, errs by up to ``n`` counts: with
    ``n`` near ``2**20`` and the momentum quantum of ``2**-24`` the force
    provider picks for asap3, a 1.4% rms change of every thermal momentum
    every step (measured on Cu256).

    A ratio above one takes information, which an empty buffer does not
    hold.  So below the bottom of each stack lie reserve words, drawn on
    demand from the counter-based generator keyed by ``key`` and the
    depth: the same words every time, so the buffer stays a bijection
    that never runs dry; the stack pointer may go negative (the buffer
    then holds less than it started with).

    Parameters
    ----------
    size : int
        Coordinates (``3 n_atoms``).
    key : numpy.ndarray
        Philox key of the reserve words (two uint64).

    Attributes
    ----------
    state_k : int64 ``[size]``
        Range-coder states in ``[2**20, 2**36)``.
    top_k : int64 ``[size]``
        Stack pointers (depth of the next free word; 0 when empty).
    ratios : int32 ``[capacity]``
        The ratio ``n`` of each step applied, ``count`` of them in use.
    """

    def __init__(self, size: int, key):
        self.size = int(size)
        self.key = np.asarray(key, dtype=np.uint64)
        self._columns = np.arange(self.size)
        self._generator = np.random.Philox(key=[0, 0])
        self.clear()

    def clear(self):
        """Empty every buffer and forget the ratios."""
        self.state_k = np.full(self.size, _LOW, dtype=np.int64)
        self.top_k = np.zeros(self.size, dtype=np.int64)
        # Row j of words_jk is depth j - base.
        self.base = 0
        self.words_jk = np.zeros((16, self.size), dtype=np.uint16)
        self.ratios = np.zeros(64, dtype=np.int32)
        self.count = 0
        self._saved = (self.state_k.copy(), self.top_k.copy(), 0)

    # -- what it holds ----------------------------------------------------

    @property
    def bits(self) -> float:
        """Information held beyond the empty buffer, summed over the
        coordinates, bits (negative when reserve words were taken), plus
        32 bits a stored ratio."""
        return float(np.log2(self.state_k / _LOW).sum()
                     + _WORD_BITS * self.top_k.sum()) + 32.0 * self.count

    @property
    def nbytes(self) -> int:
        """Memory of the states, pointers, word rows and ratios, bytes."""
        return (self.state_k.nbytes + self.top_k.nbytes
                + self.words_jk.nbytes + 4 * self.count)

    def is_empty(self) -> bool:
        """Whether every coordinate is at the empty state with no ratio."""
        return (self.count == 0 and not self.top_k.any()
                and bool(np.all(self.state_k == _LOW)))

    def used_rows(self):
        """``(base, words)``: the word rows from the lowest depth drawn to
        the highest in use, and the depth of the first row is ``-base``."""
        depth = int(self.top_k.max(initial=0))
        return self.base, self.words_jk[:depth + self.base]

    def load(self, state_k, top_k, base, words_jk, ratios):
        """Take what :meth:`used_rows`, ``state_k``, ``top_k`` and the used
        ``ratios`` of a buffer of the same size were."""
        state_k = np.asarray(state_k, dtype=np.int64)
        top_k = np.asarray(top_k, dtype=np.int64)
        base = int(base)
        if state_k.shape != (self.size,) or top_k.shape != (self.size,) \
                or not np.all((state_k >= _LOW) & (state_k < _HIGH)) \
                or words_jk.shape[1:] != (self.size,) \
                or int(top_k.min(initial=0)) < -base \
                or int(top_k.max(initial=0)) > len(words_jk) - base:
            raise ValueError('The saved buffer does not fit these atoms '
                             '(another number of atoms, or damaged).')
        self.state_k, self.top_k, self.base = state_k, top_k, base
        self.words_jk = np.zeros((max(16, 2 * len(words_jk)), self.size),
                                 dtype=np.uint16)
        self.words_jk[:len(words_jk)] = words_jk
        ratios = np.asarray(ratios, dtype=np.int32)
        self.ratios = np.zeros(max(64, 2 * len(ratios)), dtype=np.int32)
        self.ratios[:len(ratios)] = ratios
        self.count = len(ratios)
        self.checkpoint()

    # -- the two moves ----------------------------------------------------

    def scale(self, x_k, n, mask_k=None):
        """``x n / 2**20`` exactly (int64 ``[size]``), ``n`` stored.
        ``x_k``: counts below ``2**53`` in magnitude, the exact variables'
        range (the products then stay below ``2**63``).  ``mask_k`` (bool)
        leaves other coordinates and their buffers as they are."""
        x_k = np.asarray(x_k, dtype=np.int64)
        s, top = self.state_k.copy(), self.top_k.copy()
        if n < _D:
            move = s >= (n << _WORD_BITS)
            if mask_k is not None:
                move &= mask_k
            if move.any():
                cols = self._columns[move]
                self._room(int(top[cols].max()))
                # Above every pointer: a word no checkpoint relies on.
                self.words_jk[top[cols] + self.base, cols] = \
                    s[cols] & (_WORD - 1)
                top[cols] += 1
                s[cols] >>= _WORD_BITS
        elif n > _D:
            move = s < n
            if mask_k is not None:
                move &= mask_k
            if move.any():
                cols = self._columns[move]
                below = top[cols] - 1
                self._reserve(int(below.min()))
                top[cols] = below
                s[cols] = (s[cols] << _WORD_BITS) \
                    | self.words_jk[below + self.base, cols]
        s_high, digit = np.divmod(s, n)
        # x n + digit = (x div d) d n + t: t below 2**48, no overflow.
        t = (x_k & (_D - 1)) * n
        t += digit
        out = (x_k >> RATIO_BITS) * n + (t >> RATIO_BITS)
        s_new = (s_high << RATIO_BITS) | (t & (_D - 1))
        if mask_k is not None:
            s_new = np.where(mask_k, s_new, self.state_k)
            out = np.where(mask_k, out, x_k)
        self._push_ratio(n)
        self.state_k, self.top_k = s_new, top
        return out

    def unscale(self, x_k, mask_k=None):
        """The inverse of the last :meth:`scale` still held: ``x 2**20 / n``
        exactly for its ``n``, the ratio taken off.  Raises IndexError,
        with nothing changed, if no ratio is held."""
        if self.count == 0:
            raise IndexError('no ratio held')
        n = int(self.ratios[self.count - 1])
        x_k = np.asarray(x_k, dtype=np.int64)
        s_low = self.state_k & (_D - 1)
        high, low = np.divmod(x_k, n)
        # x' d + r = (x' div n) n d + t: t below 2**48 again.
        t = (low << RATIO_BITS) | s_low
        quotient, digit = np.divmod(t, n)
        out = (high << RATIO_BITS) + quotient
        s = (self.state_k >> RATIO_BITS) * n + digit
        top = self.top_k.copy()
        if n < _D:
            move = s < _LOW
        elif n > _D:
            move = s >= _HIGH
        else:
            move = None
        if move is not None and mask_k is not None:
            move &= mask_k
        if move is not None and move.any():
            cols = self._columns[move]
            if n < _D:
                below = top[cols] - 1
                self._reserve(int(below.min()))
                top[cols] = below
                s[cols] = (s[cols] << _WORD_BITS) \
                    | self.words_jk[below + self.base, cols]
            else:
                self._room(int(top[cols].max()))
                self.words_jk[top[cols] + self.base, cols] = \
                    s[cols] & (_WORD - 1)
                top[cols] += 1
                s[cols] >>= _WORD_BITS
        if mask_k is not None:
            s = np.where(mask_k, s, self.state_k)
            out = np.where(mask_k, out, x_k)
        self.count -= 1
        self.state_k, self.top_k = s, top
        return out

    def last_ratio(self):
        """The ratio ``n`` of the last step held (None if none)."""
        return int(self.ratios[self.count - 1]) if self.count else None

    # -- storage ----------------------------------------------------------

    def _push_ratio(self, n):
        if self.count == len(self.ratios):
            self.ratios = np.concatenate([self.ratios,
                                          np.zeros_like(self.ratios)])
        self.ratios[self.count] = n
        self.count += 1

    def _room(self, depth):
        """Make row ``depth`` exist above the stacks."""
        rows = len(self.words_jk)
        if depth + self.base >= rows:
            grown = np.zeros((2 * rows, self.size), dtype=np.uint16)
            grown[:rows] = self.words_jk
            self.words_jk = grown

    def _reserve(self, depth):
        """Make the reserve rows down to ``depth`` (negative) exist.  A row
        below every depth ever reached was never written, so drawing it
        now gives the same words as at any other time."""
        if depth + self.base >= 0:
            return
        new_base = max(2 * self.base, 16, -depth)
        rows = [self._reserve_row(d) for d in range(-new_base, -self.base)]
        self.words_jk = np.concatenate([np.array(rows, dtype=np.uint16),
                                        self.words_jk])
        self.base = new_base

    def _reserve_row(self, depth):
        generator = philox_stream(self._generator, self.key, depth,
                                  Lane.RESERVE)
        raw = generator.random_raw((self.size + 3) // 4)
        # Four words a draw, by shifts: no dependence on byte order.
        words = [(raw >> np.uint64(16 * i)) & np.uint64(_WORD - 1)
                 for i in range(4)]
        return np.stack(words, axis=1).reshape(-1)[:self.size]

    # -- step checkpoint (side state of the engine) -----------------------

    def checkpoint(self):
        """Remember states, pointers and the ratio count: one step pushes
        words above the pointers only and pops without writing, so rows
        need no copy."""
        saved_s, saved_top, _ = self._saved
        np.copyto(saved_s, self.state_k)
        np.copyto(saved_top, self.top_k)
        self._saved = (saved_s, saved_top, self.count)

    def rollback(self):
        """Return to the last :meth:`checkpoint`."""
        saved_s, saved_top, count = self._saved
        self.state_k = saved_s.copy()
        self.top_k = saved_top.copy()
        self.count = count
