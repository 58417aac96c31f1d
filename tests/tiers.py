"""The two tiers of the suite.

``python -m pytest`` runs the quick tier (pyproject.toml deselects tests
marked ``slow``): every module and feature, on small systems and few
steps, in about three minutes on two cores.  ``python -m pytest -m slow``
runs the long tier: the larger systems of each exactness matrix, long
runs, whole-run finite differences, the examples and the benchmarks'
quick mode.  CI runs both.
"""

import pytest

SLOW = pytest.mark.slow


def tiered(values, quick):
    """``values`` as parameters, all but those in ``quick`` in the long
    tier: a matrix keeps its cheapest cases in the quick tier."""
    quick = set(quick)
    unknown = quick - set(values)
    assert not unknown, f'not among the cases: {sorted(unknown)}'
    return [pytest.param(value, marks=() if value in quick else SLOW)
            for value in values]
