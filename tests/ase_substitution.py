"""A pytest plugin that runs ASE's own tests with the exact classes in
place of ASE's, as a user porting a script would.

Loaded with ``-p ase_substitution`` (``tests/`` on ``sys.path``) before
ASE's test modules are imported, it replaces ``VelocityVerlet``,
``Langevin``, ``Bussi``, ``NoseHooverChainNVT``, ``IsotropicMTKNPT`` and
``MTKNPT`` in ``ase.md`` and their own modules by subclasses of
``ReversibleVerlet``, ``ReversibleLangevin``, ``ReversibleBussi``,
``ReversibleNose``, ``ReversibleIsotropicNPT`` and ``ReversibleNPT``.
The only translation is the one docs/ase-dynamics.md gives a porting
user of ASE's MTK barostats, chosen by ``ASE_SUBSTITUTION_THERMOSTAT``:
``nose`` (the default; ASE's MTK classes are deterministic) passes
``thermostat='nose'`` and keeps the thermostat's chain (``tchain``,
``tloop``); ``langevin`` drops those too.  The barostat's chain
(``pchain``, ``ploop``), which the exact barostats (one piston) have no
use for, is dropped either way.  Everything else reaches the exact class
as ASE's test wrote it.

Each test's outcome, and which exact classes it constructed, are written
as JSON to the file named by ``ASE_SUBSTITUTION_REPORT``:
``{nodeid: {"outcome": "passed"|"failed"|"skipped", "ours": [names],
"message": str}}``.
"""
import json
import os

import pytest

#: ASE's name -> (ASE's modules that export it, the exact class's name).
SUBSTITUTES = {
    'VelocityVerlet': (('ase.md', 'ase.md.verlet'), 'ReversibleVerlet'),
    'Langevin': (('ase.md', 'ase.md.langevin'), 'ReversibleLangevin'),
    'Bussi': (('ase.md', 'ase.md.bussi'), 'ReversibleBussi'),
    'NoseHooverChainNVT': (('ase.md', 'ase.md.nose_hoover_chain'),
                           'ReversibleNose'),
    'IsotropicMTKNPT': (('ase.md', 'ase.md.nose_hoover_chain'),
                        'ReversibleIsotropicNPT'),
    'MTKNPT': (('ase.md', 'ase.md.nose_hoover_chain'), 'ReversibleNPT'),
}

#: The exact barostats, which take ASE's MTK calls translated.
BAROSTATS = ('ReversibleIsotropicNPT', 'ReversibleNPT')

_constructed = []
_report = {}


def _translated(name, kwargs):
    """ASE's keyword arguments ``kwargs`` for the exact class ``name``."""
    if name not in BAROSTATS:
        return kwargs
    thermostat = os.environ.get('ASE_SUBSTITUTION_THERMOSTAT', 'nose')
    dropped = ('pchain', 'ploop') if thermostat == 'nose' else (
        'tchain', 'tloop', 'pchain', 'ploop')
    kwargs = {key: value for key, value in kwargs.items()
              if key not in dropped}
    if thermostat == 'nose':
        kwargs['thermostat'] = 'nose'
    return kwargs


def _substitute(exact):
    """What stands in ASE's modules for the class ``exact``: a callable
    that notes the construction and constructs ``exact``."""
    name = exact.__name__

    def construct(*args, **kwargs):
        _constructed.append(name)
        return exact(*args, **_translated(name, kwargs))

    construct.__name__ = construct.__qualname__ = name
    return construct


def pytest_configure(config):
    import importlib
    import pkgutil

    import ase.md
    import ase_reversible

    # ASE's other classes built on these (SwitchLangevin on Langevin) are
    # not substituted by a porting user: they keep ASE's bases.
    for module in pkgutil.iter_modules(ase.md.__path__, 'ase.md.'):
        importlib.import_module(module.name)
    # So do asap3's (its Langevin is built on ASE's).
    try:
        import asap3
    except ImportError:
        pass
    else:
        for package in (asap3, getattr(asap3, 'md', None)):
            for module in pkgutil.iter_modules(
                    getattr(package, '__path__', []),
                    f'{package.__name__}.' if package else ''):
                try:
                    importlib.import_module(module.name)
                except ImportError:  # parts that need what is not here
                    pass
    for ase_name, (modules, exact_name) in SUBSTITUTES.items():
        substitute = _substitute(getattr(ase_reversible, exact_name))
        for module in modules:
            setattr(importlib.import_module(module), ase_name, substitute)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _constructed.clear()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    entry = _report.setdefault(item.nodeid, {'outcome': 'passed',
                                             'ours': [], 'message': ''})
    entry['ours'] = sorted(set(entry['ours']) | set(_constructed))
    if report.failed:
        entry['outcome'] = 'failed'
        entry['message'] = str(report.longrepr)[-2000:]
    elif report.skipped and entry['outcome'] != 'failed':
        entry['outcome'] = 'skipped'
        entry['message'] = str(report.longrepr)[-500:]


def pytest_sessionfinish(session):
    path = os.environ.get('ASE_SUBSTITUTION_REPORT')
    if path:
        with open(path, 'w') as f:
            json.dump(_report, f, indent=1, sort_keys=True)
