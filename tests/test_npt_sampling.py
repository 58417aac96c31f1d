"""ReversibleIsotropicNPT samples what ASE's IsotropicMTKNPT samples.

The comparison of the npt_sampling benchmark, on fewer atoms and steps,
with its statistics written here: the mean volume, the isothermal
compressibility and the mean potential energy of both integrators must
agree within ``Z`` of their combined standard error, and each mean
temperature reading must lie within ``Z`` of its own standard error of
what its thermostat makes it read.  The errors are measured from each run
(block averages, the jackknife, and for the compressibility the
autocorrelation time of (V - <V>)**2, the larger of the two); ``Z = 4``
standard errors is a two-sided false alarm of 6e-5 for a normal estimate,
so a failure is a difference of the distributions, not bad luck.
"""

import math

import numpy as np
import pytest
from ase import units
from ase.build import bulk
from ase.md.nose_hoover_chain import IsotropicMTKNPT
from ase.md.velocitydistribution import Stationary

from ase_reversible.app.systems import thermalize
from tiers import SLOW

#: Standard errors a difference may reach (see top).
Z = 4.0
#: Blocks of the means' errors, and of the jackknife: few and long, as the
#: piston's energy, which sets var(V), decorrelates over thousands of steps.
MEAN_BLOCKS, JACKKNIFE_BLOCKS = 20, 10


def integrated_time(x, window_c=5.0):
    """Integrated autocorrelation time ``1 + 2 sum_t rho(t)`` (samples),
    summed up to the first lag ``m >= window_c g(m)``."""
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    g = 2.0 * np.cumsum(acf / acf[0]) - 1.0
    window = np.arange(n) >= window_c * g
    return float(g[int(np.argmax(window)) if window.any() else n - 1])


def block_mean(x, blocks=MEAN_BLOCKS):
    """(mean, standard error from ``blocks`` block averages)."""
    x = np.asarray(x, float)
    length = len(x) // blocks
    means = x[:length * blocks].reshape(blocks, length).mean(axis=1)
    return float(x.mean()), float(means.std(ddof=1) / math.sqrt(blocks))


def jackknife_compressibility(volume, kT, blocks=JACKKNIFE_BLOCKS):
    """kappa_T = var(V) / (kT <V>) per GPa, its jackknife error over blocks
    and its error from the autocorrelation time of (V - <V>)**2."""
    v = np.asarray(volume, float)
    length = len(v) // blocks
    v = v[:length * blocks]
    kappa = float(v.var() / (kT * v.mean()))
    parts = v.reshape(blocks, length)
    leave_one_out = np.empty(blocks)
    for k in range(blocks):
        rest = np.delete(parts, k, axis=0).ravel()
        leave_one_out[k] = rest.var() / (kT * rest.mean())
    error = math.sqrt((blocks - 1) / blocks
                      * ((leave_one_out - leave_one_out.mean())**2).sum())
    # (V - <V>)**2 follows the piston's energy, whose correlations outlast
    # V's own: its autocorrelation time gives an error beside the blocks'.
    square = (v - v.mean())**2
    error_g = (kappa * math.sqrt(integrated_time(square) * square.var()
                                 / len(v)) / square.mean())
    return {'per_GPa': kappa * units.GPa,
            'standard_error_per_GPa': error * units.GPa,
            'standard_error_from_g_per_GPa': error_g * units.GPa}


def test_compressibility_errors_match_the_analytic_ones_of_independent_volumes():
    # Independent normal volumes: var(V) has the relative error sqrt(2/n),
    # which both errors must find.
    n, kT = 20_000, units.kB * 300.0
    volume = np.random.default_rng(3).normal(3000.0, 3.0, n)
    kappa = jackknife_compressibility(volume, kT)
    expected = kappa['per_GPa'] * math.sqrt(2 / n)
    assert kappa['per_GPa'] == pytest.approx(9.0 / (kT * 3000.0) * units.GPa,
                                             rel=4 * math.sqrt(2 / n))
    assert 0.5 < kappa['standard_error_per_GPa'] / expected < 1.6
    assert 0.8 < kappa['standard_error_from_g_per_GPa'] / expected < 1.25


def test_compressibility_error_grows_with_the_correlation_of_the_volume():
    # The same variance with each value held for 50 steps: 50 times fewer
    # independent values, an error about sqrt(50) times larger.
    n, kT = 20_000, units.kB * 300.0
    rng = np.random.default_rng(4)
    independent = rng.normal(3000.0, 3.0, n)
    held = np.repeat(rng.normal(3000.0, 3.0, n // 50), 50)
    a = jackknife_compressibility(independent, kT)
    b = jackknife_compressibility(held, kT)
    for key in ('standard_error_per_GPa', 'standard_error_from_g_per_GPa'):
        assert 3.5 < (b[key] / b['per_GPa']) / (a[key] / a['per_GPa']) < 14


def sampled(make, equilibration, total):
    """Volume, temperature reading and potential energy after each step
    past ``equilibration`` of ``total`` steps of ``make(atoms)`` on Cu 108
    (asap3 EMT, 300 K, seed 7, centre of mass at rest)."""
    import asap3
    atoms = thermalize(bulk('Cu', 'fcc', cubic=True) * (3, 3, 3), 300.0, 7)
    # ASE's chain scales every momentum by one factor: a net momentum at
    # the start would stay.
    Stationary(atoms)
    atoms.calc = asap3.EMT()
    dyn = make(atoms)
    samples = np.full((3, total + 1), np.nan)

    def observe():
        samples[:, dyn.nsteps] = (atoms.get_volume(), atoms.get_temperature(),
                                  atoms.get_potential_energy())
    dyn.attach(observe, interval=1)
    dyn.run(total)
    assert isinstance(atoms.calc, asap3.EMT)
    samples = samples[:, equilibration + 1:]
    assert np.all(np.isfinite(samples)), 'a step was not sampled'
    return samples


@SLOW
def test_reversible_npt_samples_the_volume_distribution_of_ase_mtk():
    pytest.importorskip('asap3', reason='the comparison runs asap3 EMT')
    from ase_reversible import ReversibleIsotropicNPT
    # Cu fcc, 300 K, 0 GPa, at 2.5 fs: at 5 fs the two integrators'
    # time-step errors part their mean volumes by 0.8 Å^3 at 256 atoms
    # (the benchmark's page), beyond the errors of a long run.  No way
    # back here: test_npt.py and the benchmark's round trips check the
    # reversal.  tdamp 100 steps, pdamp 1000.
    h, temperature_K, kT = 2.5 * units.fs, 300.0, units.kB * 300.0
    ours = sampled(lambda atoms: ReversibleIsotropicNPT(
        atoms, h, temperature_K, 0.0, 100 * h, 1000 * h, seed=7),
        2000, 22_000)
    theirs = sampled(lambda atoms: IsotropicMTKNPT(
        atoms, h, temperature_K, 0.0, 100 * h, 1000 * h), 2000, 22_000)

    def compressibility(volume):
        kappa = jackknife_compressibility(volume, kT)
        # The larger of the two errors: not the more optimistic one.
        return kappa['per_GPa'], max(kappa['standard_error_per_GPa'],
                                     kappa['standard_error_from_g_per_GPa'])
    for name, estimate in (('volume', lambda s: block_mean(s[0])),
                           ('compressibility',
                            lambda s: compressibility(s[0])),
                           ('potential_energy', lambda s: block_mean(s[2]))):
        (a, se_a), (b, se_b) = estimate(ours), estimate(theirs)
        assert abs(a - b) <= Z * math.hypot(se_a, se_b), (name, a, b,
                                                          se_a, se_b)
    # get_temperature() counts 3N degrees of freedom.  ASE's chain holds
    # that reading at T; the reversible Langevin step keeps the net
    # momentum at zero, so its 3N - 3 free ones are at T and the reading
    # is T (1 - 1/N) (BAOAB's end-of-step momenta lower it further by
    # h^2 <omega^2> / 4, about 0.2% for copper at 2.5 fs: inside the bound).
    n = 108
    for samples, expected in ((theirs, temperature_K),
                              (ours, temperature_K * (1 - 1 / n))):
        mean, se = block_mean(samples[1])
        assert abs(mean - expected) <= Z * se, (mean, se, expected)
