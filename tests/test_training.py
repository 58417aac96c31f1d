"""Training through exact retraces (examples/fit_rdf.py), its fast pieces.

The smoothed g(r) and its torch pullback against finite differences, and
one short epoch of the fit: the retrace ends on the epoch's start bit for
bit and the parameter gradient it returns matches central differences of
the same pipeline.  The whole example in its quick mode runs in
tests/test_examples.py (slow tier).
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip('torch', reason='the RDF loss is computed in torch')

EXAMPLE = Path(__file__).resolve().parent.parent / 'examples' / 'fit_rdf.py'


@pytest.fixture(scope='module')
def fit_rdf():
    spec = importlib.util.spec_from_file_location('fit_rdf', EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules['fit_rdf'] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_rdf_pullback_matches_finite_differences(fit_rdf):
    atoms = fit_rdf.liquid_argon(2)
    atoms.rattle(0.2, seed=3)
    rdf = fit_rdf.SmoothRDF(atoms, 5.2)
    w_b = np.random.default_rng(0).standard_normal(len(rdf.r_b))
    x_nc = atoms.positions
    grad_nc = rdf.pullback(x_nc, w_b)
    u_nc = np.random.default_rng(1).standard_normal(x_nc.shape)
    h = 1e-5
    fd = (w_b @ rdf.values(x_nc + h * u_nc)
          - w_b @ rdf.values(x_nc - h * u_nc)) / (2 * h)
    assert np.vdot(grad_nc, u_nc) == pytest.approx(fd, rel=1e-7)
    # A liquid's g(r) starts near 0 inside the core and peaks near σ 2^1/6.
    g_b = rdf.values(x_nc)
    assert g_b.shape == rdf.r_b.shape and np.all(np.isfinite(g_b))


def test_rdf_refuses_a_reach_beyond_half_the_box(fit_rdf):
    atoms = fit_rdf.liquid_argon(2)
    with pytest.raises(ValueError, match='half the box'):
        fit_rdf.SmoothRDF(atoms, 6.0)


def test_one_epoch_returns_exactly_and_its_gradient_is_right(fit_rdf):
    """A tiny epoch of the LJ student: back at the start bit for bit, and
    dL/dε through the whole pipeline (forward, mean g(r), loss, one retrace
    with loss=) against central differences of the same pipeline (the
    comparison with float runs is benchmarks/studies/training.py's)."""
    size = fit_rdf.Size(repeat=2, r_max=5.2, equilibrate=0, target_steps=0,
                        epochs=1, steps=40, every=10, window=10,
                        learning_rate=0.01, mlp_cutoff=8.5,
                        mlp_learning_rate=0.001, pretrain_steps=0)
    atoms = fit_rdf.liquid_argon(2)
    rdf = fit_rdf.SmoothRDF(atoms, size.r_max)
    target_b = rdf.values(atoms.positions)
    x0, p0 = atoms.positions.copy(), atoms.get_momenta()

    def run(epsilon, size=size):
        atoms.positions[:] = x0
        atoms.set_momenta(p0)
        calc = fit_rdf.LennardJones(epsilon=epsilon, sigma=3.6)
        return fit_rdf.epoch(atoms, calc, ('epsilon',), rdf, target_b, size,
                             seed=5)

    loss, _, grads, exact, _ = run(fit_rdf.EPSILON)
    assert exact is True  # np.array_equal on positions and momenta
    # The gradient of each observed state flows back only `window` steps:
    # compare the untruncated one (window=None) with the difference.
    size_full = fit_rdf.Size(**{**size.__dict__, 'window': None})
    full = run(fit_rdf.EPSILON, size_full)[2]
    # Central differences of the exact runs themselves: below h = 1e-4 ε
    # their rounding shows (the loss of an exact run moves in steps of the
    # grid); at 1e-3 ε they agreed to 3e-6 (measured: -43.61882 against
    # -43.61869 from the retrace).
    h = 1e-3 * fit_rdf.EPSILON
    fd = (run(fit_rdf.EPSILON + h, size_full)[0]
          - run(fit_rdf.EPSILON - h, size_full)[0]) / (2 * h)
    assert full['epsilon'] == pytest.approx(fd, rel=1e-5)
    # The truncated gradient is another number, but not far off here.
    assert grads['epsilon'] != full['epsilon']
    assert np.sign(grads['epsilon']) == np.sign(full['epsilon'])
