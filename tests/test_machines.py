"""The emulated machines of ``tests/machines.py`` do compute other bits:
without that, a test that crosses them could not fail."""

from machines import bits_of, emulation_works


def test_blas_core_types_give_other_bits(tmp_path):
    assert emulation_works(tmp_path)


def test_a_machine_is_repeatable(tmp_path):
    assert bits_of('sse4', 'np.exp(x) @ x.T', tmp_path) == bits_of(
        'sse4', 'np.exp(x) @ x.T', tmp_path)


def test_correctly_rounded_operations_agree_across_machines(tmp_path):
    expression = '(x * x + x / 3.0 - np.sqrt(x)).sum(axis=1)'
    assert len({bits_of(machine, expression, tmp_path)
                for machine in ('native', 'avx2', 'sse4')}) == 1
