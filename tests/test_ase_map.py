"""Each ASE dynamics the map (docs/ase-dynamics.md) lists as covered takes
ASE's own call with only the class name swapped, or refuses an argument
with a message that gives its translation.

For every parameter of the ASE class's signature (as installed: an older
ASE has fewer), the table below says which value an ASE user passes and
whether the exact class takes it (``TAKEN``) or refuses it with a message
holding the given words.  A parameter missing from the table fails the
test, so a new ASE argument cannot go unmapped.  The call with every taken
argument then runs out and back, bit for bit.
"""

import importlib

import numpy as np
import pytest
from ase import units
from ase.calculators.emt import EMT
from ase.md.velocitydistribution import Stationary

import ase_reversible
from ase_reversible.app.systems import copper_bulk
from exactness import assert_runs_back, assert_same_state, snapshot

TAKEN = object()
DT = 5 * units.fs


def _kT(temperature_K):
    return units.kB * temperature_K


#: What every ASE dynamics takes for its output, passed on to its base.
FILES = {'trajectory': ('file', TAKEN), 'logfile': ('file', TAKEN),
         'loginterval': (2, TAKEN), 'append_trajectory': (True, TAKEN)}

#: ASE's MTK barostats' arguments (the isotropic and the whole cell's).
MTK = {
    'temperature_K': (300.0, TAKEN),
    'pressure_au': (1 * units.GPa, TAKEN),
    'tdamp': (100 * DT, TAKEN),
    'pdamp': (1000 * DT, TAKEN),
    'tchain': (3, 'leave tchain out'),
    'pchain': (3, 'leave pchain out'),
    'tloop': (1, 'leave tloop out'),
    'ploop': (1, 'leave ploop out'),
    **FILES,
}

#: ASE class -> (module, exact class, {parameter: (value, TAKEN or the
#: words the refusal must hold)}).  Values that need a file are built by
#: ``_value``.  ``append_trajectory`` is a keyword every ASE dynamics passes
#: on to its base class.
MAP = {
    'VelocityVerlet': ('ase.md.verlet', 'ReversibleVerlet', FILES),
    'Langevin': ('ase.md.langevin', 'ReversibleLangevin', {
        'temperature_K': (300.0, TAKEN),
        'friction': (0.02 / units.fs, TAKEN),
        'fixcm': (True, TAKEN),
        'temperature': (_kT(300.0), 'temperature_K=300'),
        'rng': (np.random.default_rng(1), TAKEN),
        **FILES,
    }),
    'Bussi': ('ase.md.bussi', 'ReversibleBussi', {
        'temperature_K': (300.0, TAKEN),
        'taut': (100 * units.fs, TAKEN),
        'rng': (np.random.default_rng(1), TAKEN),
        **FILES,
    }),
    'NoseHooverChainNVT': ('ase.md.nose_hoover_chain', 'ReversibleNose', {
        'temperature_K': (300.0, TAKEN),
        'tdamp': (100 * DT, TAKEN),
        'tchain': (3, TAKEN),
        'tloop': (1, TAKEN),
        **FILES,
    }),
    'IsotropicMTKNPT': ('ase.md.nose_hoover_chain', 'ReversibleIsotropicNPT',
                        MTK),
    'MTKNPT': ('ase.md.nose_hoover_chain', 'ReversibleNPT', MTK),
}

#: Parameters that are two ways of giving one value: ASE takes exactly one.
ALTERNATIVES = {'temperature': 'temperature_K'}


def _ase_class(name):
    module, _, _ = MAP[name]
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        pytest.skip(f'this ASE has no {module}.{name}')


def _parameters(cls):
    import inspect
    names = [p.name for p in inspect.signature(cls.__init__).parameters
             .values() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
    return [n for n in names if n not in ('self', 'atoms', 'timestep')] + [
        'append_trajectory']


def _value(value, tmp_path, name):
    return str(tmp_path / f'{name}.out') if value == 'file' else value


def _atoms():
    atoms = copper_bulk((2, 2, 2), temperature_K=300, seed=3)
    Stationary(atoms)   # as ASE's docs do before a Nosé-Hoover run
    atoms.calc = EMT()
    return atoms


@pytest.mark.parametrize('ase_name', sorted(MAP))
def test_every_ase_argument_is_mapped(ase_name):
    missing = set(_parameters(_ase_class(ase_name))) - set(MAP[ase_name][2])
    assert not missing, (f'{ase_name} has arguments the map does not give: '
                         f'{sorted(missing)}; add them to MAP and to '
                         'docs/ase-dynamics.md')


@pytest.mark.parametrize('ase_name', sorted(MAP))
def test_the_ase_call_runs_exactly(ase_name, tmp_path):
    _ase_class(ase_name)
    _, exact_name, table = MAP[ase_name]
    cls = getattr(ase_reversible, exact_name)
    kwargs = {name: _value(value, tmp_path, name)
              for name, (value, verdict) in table.items()
              if verdict is TAKEN}
    dyn = cls(_atoms(), DT, **kwargs)
    cell = dyn.atoms.cell.array.copy()
    assert_runs_back(dyn, 4)
    assert np.array_equal(dyn.atoms.cell.array, cell)


def _refused_cases():
    for ase_name, (_, exact_name, table) in sorted(MAP.items()):
        for name, (value, verdict) in table.items():
            if verdict is not TAKEN:
                yield pytest.param(ase_name, name, id=f'{ase_name}-{name}')


def test_tloop_other_than_one_is_refused():
    atoms = _atoms()
    with pytest.raises((TypeError, ValueError), match='tloop'):
        ase_reversible.ReversibleNose(atoms, DT, temperature_K=300,
                                      tdamp=100 * DT, tchain=3, tloop=2)


@pytest.mark.parametrize('ase_name, argument', list(_refused_cases()))
def test_a_refused_argument_gives_its_translation(ase_name, argument,
                                                  tmp_path):
    _ase_class(ase_name)
    _, exact_name, table = MAP[ase_name]
    cls = getattr(ase_reversible, exact_name)
    kwargs = {name: _value(value, tmp_path, name)
              for name, (value, verdict) in table.items()
              if verdict is TAKEN and name != ALTERNATIVES.get(argument)}
    value, words = table[argument]
    kwargs[argument] = value
    atoms = _atoms()
    start = snapshot(atoms)
    with pytest.raises(TypeError, match=words):
        cls(atoms, DT, **kwargs)
    assert_same_state(atoms, start)   # nothing was changed
    assert not any(tmp_path.iterdir())  # nor any file opened


def test_a_cell_mask_is_refused():
    atoms = _atoms()
    start = snapshot(atoms)
    with pytest.raises(TypeError, match='MaskedMTKNPT'):
        ase_reversible.ReversibleNPT(
            atoms, DT, temperature_K=300, pressure_au=0.0, tdamp=100 * DT,
            pdamp=1000 * DT, mask=(True, True, False))
    assert_same_state(atoms, start)


def test_a_temperature_in_ev_is_refused_with_its_value_in_kelvin():
    atoms = _atoms()
    start = snapshot(atoms)
    with pytest.raises(ValueError, match='for 300 K. Pass temperature_K=300'):
        ase_reversible.ReversibleLangevin(atoms, DT, _kT(300.0),
                                          0.02 / units.fs)
    assert_same_state(atoms, start)
