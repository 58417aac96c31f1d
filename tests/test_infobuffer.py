"""The information buffer and the step noise: exact, and what they claim.

The buffer's moves are checked as bijections over random values, ratios
and masks (hypothesis), its size against the -log2(c) bits per move that
no exact scheme can beat, and the noise for being drawn again bit for bit.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ase_reversible.core.infobuffer import (DIGIT_BITS, BufferUnderflowError,
                                            InformationBuffer, friction_ratio)
from ase_reversible.core.noise import (Lane, StepNoise, philox_stream,
                                       portable_log, step_key)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 2**DIGIT_BITS - 1),
       moves=st.integers(1, 300), masked=st.booleans())
def test_scale_down_then_up_restores_values_and_empties_the_buffer(
        seed, n, moves, masked):
    rng = np.random.default_rng(seed)
    size = 37
    buffer = InformationBuffer(size, n)
    mask = rng.random(size) < 0.7 if masked else None
    x0 = rng.integers(-2**52, 2**52, size)
    x, kicks = x0.copy(), []
    for _ in range(moves):
        kick = rng.integers(-2**44, 2**44, size)
        kicks.append(kick)
        x = buffer.scale_down(x, mask) + kick
    moved = not np.array_equal(x, x0)
    for kick in reversed(kicks):
        x = buffer.scale_up(x - kick, mask)
    assert moved
    assert np.array_equal(x, x0)
    assert buffer.is_empty()


@pytest.mark.parametrize('c', [0.9999, 0.99, 0.95, 0.5, 0.01])
def test_the_buffer_holds_minus_log2_c_bits_per_move(c):
    n = friction_ratio(c)
    buffer = InformationBuffer(300, n)
    rng = np.random.default_rng(1)
    x = rng.integers(-2**45, 2**45, 300)
    for _ in range(1000):
        x = buffer.scale_down(x) + rng.integers(-2**40, 2**40, 300)
    per_move = buffer.bits / 300 / 1000
    assert per_move == pytest.approx(-math.log2(n / 2**DIGIT_BITS), rel=1e-3)
    # Stored as 16-bit words: within one word per coordinate of that.
    assert buffer.words_jk.itemsize == 2
    assert buffer.top_k.max() <= per_move * 1000 / 16 + 1


def test_the_product_is_within_n_counts_of_c_x():
    n = friction_ratio(0.95)
    buffer = InformationBuffer(10_000, n)
    x = np.random.default_rng(2).integers(-2**50, 2**50, 10_000)
    y = buffer.scale_down(x)
    assert np.abs(y - x * (n / 2**DIGIT_BITS)).max() < n


def test_undoing_a_move_that_never_happened_raises_and_changes_nothing():
    buffer = InformationBuffer(5, friction_ratio(0.9))
    x = np.arange(5) * 12345
    with pytest.raises(BufferUnderflowError, match='never applied'):
        buffer.scale_up(x)
    assert buffer.is_empty()
    x1 = buffer.scale_down(x)
    assert np.array_equal(buffer.scale_up(x1), x)
    with pytest.raises(BufferUnderflowError):
        buffer.scale_up(x)
    assert buffer.is_empty()


def test_rollback_returns_to_the_checkpoint():
    buffer = InformationBuffer(50, friction_ratio(0.5))
    rng = np.random.default_rng(3)
    x = rng.integers(-2**40, 2**40, 50)
    for _ in range(40):
        x = buffer.scale_down(x)
    buffer.checkpoint()
    state, top = buffer.state_k.copy(), buffer.top_k.copy()
    buffer.scale_down(x)
    buffer.rollback()
    assert np.array_equal(buffer.state_k, state)
    assert np.array_equal(buffer.top_k, top)
    for _ in range(40):
        x = buffer.scale_up(x)
    assert buffer.is_empty()


def test_friction_ratio_refuses_factors_outside_zero_one():
    for c in (0.0, 1.0, -0.5, float('nan')):
        with pytest.raises(ValueError, match=r'\(0, 1\)'):
            friction_ratio(c)


def test_step_noise_is_drawn_again_bit_for_bit_and_differs_between_steps():
    noise = StepNoise(301)
    key = step_key(11, 0.49)
    a = noise.normals(key, 5)
    assert a.shape == (301,)
    assert np.array_equal(noise.normals(key, 5), a)
    assert np.array_equal(StepNoise(301).normals(key, 5), a)
    assert not np.array_equal(noise.normals(key, 6), a)
    assert not np.array_equal(noise.normals(key, -5), a)
    assert not np.array_equal(noise.normals(step_key(12, 0.49), 5), a)
    assert not np.array_equal(noise.normals(step_key(11, 0.5), 5), a)


def test_the_consumers_of_a_key_draw_on_lanes_of_their_own():
    """Each lane starts its own words at every step index: no consumer of
    a key reads another's."""
    key, generator = step_key(11, 0.49), np.random.Philox(key=[0, 0])
    words = {lane: philox_stream(generator, key, 5, lane).random_raw(8)
             for lane in Lane}
    assert len(words) == 3
    for lane in Lane:
        for other in Lane:
            if other is not lane:
                assert not np.isin(words[lane], words[other]).any()
    assert np.array_equal(philox_stream(generator, key, 5,
                                        Lane.NOISE).random_raw(8),
                          words[Lane.NOISE])


def test_step_noise_is_standard_normal():
    noise = StepNoise(3000)
    key = step_key(5, 0.25)
    z = np.concatenate([noise.normals(key, k) for k in range(100)])
    # 300,000 deviates: mean and variance within 5 standard errors, and
    # the fourth moment of a Gaussian (3) within 5 of its standard errors.
    assert abs(z.mean()) < 5 / math.sqrt(z.size)
    assert abs(z.var() - 1) < 5 * math.sqrt(2 / z.size)
    assert abs(np.mean(z**4) - 3) < 5 * math.sqrt(96 / z.size)


def test_portable_log_agrees_with_numpy_to_a_few_ulp():
    s = np.exp(np.random.default_rng(4).uniform(-700, 700, 20_000))
    s = np.concatenate([s, [1.0, 0.5, 2.0, 5e-324, 1e308]])
    exact = np.log(s)
    assert np.all(np.abs(portable_log(s) - exact)
                  <= 8 * np.spacing(np.maximum(np.abs(exact), 1.0)))
