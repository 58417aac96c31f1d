"""ReversibleLangevin and ReversibleBussi set up alike for the tests.

Ar13 with ASE's Lennard-Jones, a 5 fs step towards 300 K and seed 1
unless a test says otherwise; the coupling is a friction of 0.02 / fs
(Langevin) or a time constant of 100 fs (Bussi).
"""

from ase import units

from ase_reversible import ReversibleBussi, ReversibleLangevin

from conftest import CALCULATORS, argon_cluster

FRICTION = 0.02 / units.fs
TAUT = 100 * units.fs

#: name -> (class, its coupling's parameter, the tests' value of it).
THERMOSTATS = {'langevin': (ReversibleLangevin, 'friction', FRICTION),
               'bussi': (ReversibleBussi, 'taut', TAUT)}


def ar13(temperature_K=60):
    """Ar13 with thermal momenta at ``temperature_K`` and ASE's
    Lennard-Jones."""
    atoms = argon_cluster(2, temperature_K)
    atoms.calc = CALCULATORS['ase-lj']()
    return atoms


def resume(name, atoms, **kwargs):
    """The thermostat ``name`` constructed as a user resuming a run would:
    5 fs, 300 K, the tests' coupling, no seed (the record's is taken)."""
    cls, coupling, value = THERMOSTATS[name]
    arguments = {'temperature_K': 300, coupling: value, **kwargs}
    return cls(atoms, 5 * units.fs, **arguments)


def thermostat(name, atoms, dt_fs=5, temperature_K=300, **kwargs):
    """A new run of the thermostat ``name``: time step ``dt_fs`` (fs),
    seed 1 unless given."""
    cls, coupling, value = THERMOSTATS[name]
    kwargs.setdefault('seed', 1)
    kwargs.setdefault(coupling, value)
    return cls(atoms, dt_fs * units.fs, temperature_K=temperature_K,
               **kwargs)


def langevin(atoms, dt_fs=5, temperature_K=300, **kwargs):
    return thermostat('langevin', atoms, dt_fs, temperature_K, **kwargs)


def bussi(atoms, dt_fs=5, temperature_K=300, **kwargs):
    return thermostat('bussi', atoms, dt_fs, temperature_K, **kwargs)


def assert_buffers_empty(dyn):
    """The thermostat's information buffers exist and hold nothing."""
    step = (dyn.friction_step if isinstance(dyn, ReversibleLangevin)
            else dyn.rescale_step)
    buffers = step.buffers.values()
    assert buffers and all(b.is_empty() for b in buffers)
