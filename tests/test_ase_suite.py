"""ASE's own molecular-dynamics tests, run with the exact classes in place
of ASE's (the plugin ``ase_substitution`` says how): every test that
constructs one of the exact classes passes, but for those listed in
:data:`EXCEPTIONS`, each with its reason, which docs/ase-dynamics.md
gives too.

The tests are those of ASE's ``ase/test/md`` and the five elsewhere in
ASE's suite that run these classes with only ASE and asap3; they ship
with ASE, so the installed version's are run (this suite was written
against ASE 3.29's).  ASE's own settings apply: its ``conftest.py`` turns
every warning into an error and skips the asap3 tests where asap3 is not
installed.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tiers import SLOW

pytest.importorskip('ase.test.md', reason='this ASE installs no tests')

HERE = Path(__file__).parent
ROOT = HERE.parent

#: ASE's test modules run.
MODULES = ('ase.test.md', 'ase.test.constraints.test_hookean',
           'ase.test.test_forcecurve', 'ase.test.forcefields.test_rattle',
           'ase.test.forcefields.test_rattle_linear',
           'ase.test.constraints.test_fix_symmetry')

_OUTSIDE = ('the momenta (or positions) are changed outside the dynamics '
            'during the run; the exact class takes each change with an '
            'AnchorMovedWarning (reversal then leads back to that point), '
            'which ASE\'s suite turns into an error')

#: ASE's test (its function's name) -> why it fails with the exact classes.
EXCEPTIONS = {
    'test_fixrotation_asap': 'FixRotation applied by an observer at every '
                             'step: ' + _OUTSIDE,
    'test_verlet_thermostats_asap': 'thermalize_momenta in mid-run and '
                                    'set_timestep: ' + _OUTSIDE,
    'test_langevin_asapcompat': 'it asks for the coefficients of ASE\'s '
                                'Langevin scheme (fr, c1 to c5, rnd_pos, '
                                'rnd_vel) that asap3\'s subclass of ASE\'s '
                                'class reads; the exact step is BAOAB and '
                                'has none',
}


def _importable(name):
    try:
        __import__(name)
    except ImportError:
        return False
    return True


def _function(nodeid):
    return nodeid.split('::')[-1].split('[')[0]


def ase_tests(folder, modules, thermostat='nose'):
    """Run ASE's tests in ``modules`` with the exact classes in place (the
    barostats with ``thermostat``) in ``folder``; their outcomes, by node
    id (the plugin's report)."""
    path = folder / 'report.json'
    env = dict(os.environ, ASE_SUBSTITUTION_REPORT=str(path),
               ASE_SUBSTITUTION_THERMOSTAT=thermostat)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(HERE), str(ROOT)] + [p for p in [env.get('PYTHONPATH')] if p])
    result = subprocess.run(
        [sys.executable, '-m', 'pytest', '-q', '-p', 'ase_substitution',
         '-p', 'no:cacheprovider', '--pyargs', *modules],
        cwd=folder, env=env, capture_output=True, text=True, timeout=900)
    assert path.exists(), result.stdout[-3000:] + result.stderr[-3000:]
    return json.loads(path.read_text())


@pytest.fixture(scope='module')
def report(tmp_path_factory):
    """ASE's tests' outcomes, the barostats with Nosé's thermostat."""
    return ase_tests(tmp_path_factory.mktemp('ase-suite'), MODULES)


@SLOW
def test_every_test_that_constructs_an_exact_class_passes(report):
    ours = {nodeid: entry for nodeid, entry in report.items()
            if entry['ours']}
    # Every class substituted is constructed somewhere: the substitution
    # reached ASE's tests.
    # (ASE's tests of Nosé and the barostats need asap3.)
    constructed = {name for entry in ours.values() for name in entry['ours']}
    assert constructed >= {'ReversibleVerlet', 'ReversibleLangevin',
                           'ReversibleBussi'}
    if _importable('asap3'):
        assert constructed == {'ReversibleVerlet', 'ReversibleLangevin',
                               'ReversibleBussi', 'ReversibleNose',
                               'ReversibleIsotropicNPT', 'ReversibleNPT'}
    failed = {nodeid: entry['message'][-600:] for nodeid, entry
              in ours.items() if entry['outcome'] == 'failed'
              and _function(nodeid) not in EXCEPTIONS}
    assert not failed, json.dumps(failed, indent=1)


@SLOW
def test_each_exception_still_fails_and_is_documented(report):
    """An exception that starts to pass is taken off the list; each is
    named, with its reason, in docs/ase-dynamics.md."""
    outcomes = {}
    for nodeid, entry in report.items():
        if _function(nodeid) in EXCEPTIONS and entry['ours']:
            outcomes.setdefault(_function(nodeid), set()).add(
                entry['outcome'])
    passing = {name for name, seen in outcomes.items() if 'passed' in seen}
    assert not passing, f'these now pass: take them off EXCEPTIONS: ' \
                        f'{sorted(passing)}'
    page = (ROOT / 'docs' / 'ase-dynamics.md').read_text()
    assert not [name for name in EXCEPTIONS if f'`{name}`' not in page]


@SLOW
def test_the_substitution_leaves_ases_other_tests_passing(report):
    """ASE's tests that construct none of the exact classes (its Andersen,
    its Berendsen, SwitchLangevin on ASE's own Langevin, the loggers)
    pass as with ASE alone: the substitution changed nothing else."""
    failed = [nodeid for nodeid, entry in report.items()
              if not entry['ours'] and entry['outcome'] == 'failed']
    assert not failed


@SLOW
def test_ases_mtk_tests_pass_with_the_langevin_barostats_too(tmp_path):
    """ASE's tests of its MTK classes with the default (Langevin) exact
    barostats: the thermostat's chain dropped, the energy less the heat
    the thermostat added conserved within ASE's 1e-3 eV."""
    pytest.importorskip('asap3', reason='ASE\'s MTK tests run asap3')
    report = ase_tests(tmp_path, ['ase.test.md.test_nose_hoover_chain'],
                       thermostat='langevin')
    ours = {nodeid: entry for nodeid, entry in report.items()
            if set(entry['ours']) & {'ReversibleIsotropicNPT',
                                     'ReversibleNPT'}}
    assert len(ours) == 8
    assert all(entry['outcome'] == 'passed' for entry in ours.values()), \
        {nodeid: entry['message'][-600:] for nodeid, entry in ours.items()}
