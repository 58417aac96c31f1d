"""Exact multiplication by a ratio below one, with the lost digits kept.

Friction multiplies momenta by ``c = exp(-gamma h) < 1``.  On integers that
loses information (several counts map to one), so it cannot be undone --
unless the digits it drops are kept.  Maclaurin, Duvenaud and Adams
("Gradient-based hyperparameter optimization through reversible learning",
ICML 2015) multiply a fixed-point value ``x`` exactly by ``n / d`` with an
information buffer ``B``:

* push the ``d``-ary digit ``x mod d`` onto ``B`` and keep ``x div d``;
* multiply by ``n`` and add the ``n``-ary digit popped from ``B``.

Both moves are bijections, so the product is undone by the same moves the
other way round (push ``x' mod n``, pop a ``d``-ary digit).  ``B`` grows by
``log2(d / n) = -log2(c)`` bits per multiplication, which is the least any
exact scheme can keep, and the result differs from ``c x`` by less than
``n`` counts, a perturbation far below the thermal noise that comes with
friction.

Here every coordinate has its own buffer, held as in range coding (rANS,
J. Duda, "Asymmetric numeral systems", 2013): the low end of ``B`` is a
state ``s`` in ``[L, 2**16 L)`` with ``L = n``, the rest a stack of 16-bit
words.  Pushing and popping are done in one: ``z = s d + (x mod d)``,
``s' = z div n`` and the popped digit ``z mod n``.  That grows ``s`` by
``d / n``; when it leaves the interval its low word goes onto the stack.
The reverse move knows from ``s'`` alone whether that happened
(``s' < L d / n`` only then) and takes the word back first.  So a
coordinate moves one word in ``16 / log2(d / n)`` multiplications, a
multiplication of all coordinates is a fixed handful of array operations
(no loop over coordinates, no big integers), and every intermediate
``z < 2**16 L d`` fits int64.  An empty buffer is the state ``L`` with no
words.
"""

from __future__ import annotations

import numpy as np

#: Bits per stack word and of the denominator ``d = 2**DIGIT_BITS``.
WORD_BITS = 16
DIGIT_BITS = 16
_WORD = 1 << WORD_BITS
_reduce_max = np.maximum.reduce
_D = 1 << DIGIT_BITS


class BufferUnderflowError(RuntimeError):
    """A coordinate's buffer was asked for digits it never held."""


def friction_ratio(c: float) -> int:
    """The numerator ``n`` of the exact ratio ``n / 2**DIGIT_BITS`` nearest
    to ``c`` (``0 < c < 1``), kept within ``[1, 2**DIGIT_BITS - 1]``."""
    if not 0.0 < c < 1.0:
        raise ValueError(f'The friction factor must lie in (0, 1), got {c!r}')
    return int(min(max(round(c * _D), 1), _D - 1))


class InformationBuffer:
    """Per-coordinate buffers of the digits exact friction drops.

    Parameters
    ----------
    size : int
        Number of coordinates (``3 n_atoms``).
    n : int
        Numerator of the ratio ``n / 2**DIGIT_BITS`` it serves.

    Attributes
    ----------
    state_k : int64 ``[size]``
        Range-coder states, in ``[L, 2**16 L)`` with ``L = n``.
    top_k : int64 ``[size]``
        Words on each coordinate's stack.
    words_jk : uint16 ``[capacity, size]``
        The stacks, column ``k`` for coordinate ``k``.
    """

    def __init__(self, size: int, n: int):
        self.n = int(n)
        self.low = self.n  # L
        self._high = _WORD * self.n  # 2**16 L
        self.state_k = np.full(size, self.low, dtype=np.int64)
        self.top_k = np.zeros(size, dtype=np.int64)
        self.words_jk = np.zeros((16, size), dtype=np.uint16)
        self._columns = np.arange(size)
        self._saved = (self.state_k.copy(), self.top_k.copy())

    def clear(self):
        """Empty every coordinate's buffer."""
        self.state_k = np.full_like(self.state_k, self.low)
        self.top_k = np.zeros_like(self.top_k)
        self.words_jk = self.words_jk[:16].copy()
        self.checkpoint()

    def load(self, state_k, top_k, words_jk):
        """Take the contents another buffer of the same ``n`` and size had
        (its ``state_k``, ``top_k`` and the used rows of
        ``words_jk``)."""
        if state_k.shape != self.state_k.shape or not np.all(
                (state_k >= self.low) & (state_k < self._high)):
            raise ValueError('The saved buffer does not fit: other size or '
                             'friction ratio.')
        self.state_k = np.array(state_k, dtype=np.int64)
        self.top_k = np.array(top_k, dtype=np.int64)
        depth = max(16, len(words_jk))
        self.words_jk = np.zeros((depth, len(self.state_k)), dtype=np.uint16)
        self.words_jk[:len(words_jk)] = words_jk
        self.checkpoint()

    # -- size ------------------------------------------------------------

    @property
    def bits(self) -> float:
        """Information held, summed over coordinates (bits)."""
        return float(np.log2(self.state_k / self.low).sum()
                     + WORD_BITS * self.top_k.sum())

    @property
    def nbytes(self) -> int:
        """Memory the buffer uses now (bytes)."""
        return (self.state_k.nbytes + self.top_k.nbytes
                + self.words_jk[:int(self.top_k.max(initial=0))].nbytes)

    def is_empty(self) -> bool:
        """Whether every coordinate is back at the empty state."""
        return (not self.top_k.any()) and bool(np.all(self.state_k
                                                      == self.low))

    # -- the two moves ---------------------------------------------------

    def scale_down(self, x_k: np.ndarray, mask_k=None) -> np.ndarray:
        """``x * n / d`` exactly, as int64 ``[size]``, the dropped digits
        pushed.  ``mask_k`` (bool) leaves other coordinates as they are
        and their buffers untouched."""
        x_k = np.asarray(x_k, dtype=np.int64)
        z = self.state_k << DIGIT_BITS
        z |= x_k & (_D - 1)
        s, digit = np.divmod(z, self.n)
        if mask_k is not None:
            s = np.where(mask_k, s, self.state_k)
        top = self.top_k
        if _reduce_max(s) >= self._high:
            cols = self._columns[s >= self._high]
            top = top.copy()
            if int(top[cols].max()) >= len(self.words_jk):
                self._grow()
            # Above every pointer: a word no checkpoint relies on.
            self.words_jk[top[cols], cols] = s[cols] & (_WORD - 1)
            top[cols] += 1
            s[cols] >>= WORD_BITS
        self.state_k, self.top_k = s, top
        out = (x_k >> DIGIT_BITS) * self.n + digit
        return out if mask_k is None else np.where(mask_k, out, x_k)

    def scale_up(self, x_k: np.ndarray, mask_k=None) -> np.ndarray:
        """The inverse of :meth:`scale_down`: ``x * d / n`` exactly, taking
        back the digits it pushed.  Raises :class:`BufferUnderflowError`,
        with nothing changed, if the buffer does not hold them: the
        multiplication being undone never happened."""
        x_k = np.asarray(x_k, dtype=np.int64)
        s, top = self.state_k, self.top_k
        refill = s < _D  # L d / n with L = n: only a spilled state is here
        if mask_k is not None:
            refill &= mask_k
        if refill.any():
            cols = self._columns[refill]
            below = top[cols] - 1
            if int(below.min()) < 0:
                raise BufferUnderflowError(
                    'The information buffer holds no digits for '
                    f'{int(np.count_nonzero(below < 0))} coordinates: the '
                    'friction being undone was never applied.')
            s, top = s.copy(), top.copy()
            top[cols] = below
            s[cols] = (s[cols] << WORD_BITS) | self.words_jk[below, cols]
        high, low = np.divmod(x_k, self.n)
        z = s * self.n
        z += low
        s_new = z >> DIGIT_BITS
        self.state_k = s_new if mask_k is None else np.where(mask_k, s_new,
                                                             self.state_k)
        self.top_k = top
        out = (high << DIGIT_BITS) | (z & (_D - 1))
        return out if mask_k is None else np.where(mask_k, out, x_k)

    def _grow(self):
        grown = np.zeros((2 * len(self.words_jk), self.words_jk.shape[1]),
                         dtype=self.words_jk.dtype)
        grown[:len(self.words_jk)] = self.words_jk
        self.words_jk = grown

    # -- step checkpoint (side state of the engine) ----------------------

    def checkpoint(self):
        """Remember the states and stack pointers.  Words below the
        pointers are never overwritten within one step (a push goes above,
        a pop only moves the pointer), so the pointers are enough."""
        saved_s, saved_top = self._saved
        np.copyto(saved_s, self.state_k)
        np.copyto(saved_top, self.top_k)

    def rollback(self):
        """Return to the last :meth:`checkpoint`."""
        saved_s, saved_top = self._saved
        self.state_k = saved_s.copy()
        self.top_k = saved_top.copy()
