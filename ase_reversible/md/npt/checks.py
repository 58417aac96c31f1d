"""What :class:`~.isotropic.ReversibleIsotropicNPT` checks of its
arguments and atoms, and its warning of a record it cannot resume."""

from __future__ import annotations

import math
import warnings

import numpy as np
from ase import units
from ase.calculators.calculator import PropertyNotImplementedError

from ...core.arguments import checked_positive
from ...errors import AnchorMovedWarning, UnsupportedConstraintError
from ..checks import check_energy_watch, check_timestep, fixed
from .system import cell_volume


def _warn_new_run(why):
    warnings.warn(
        f'The restart record of these atoms cannot be resumed ({why}); '
        'ReversibleIsotropicNPT starts a new run here, with this cell as '
        'the reference cell and time from 0.', AnchorMovedWarning,
        stacklevel=5)


#: eV/Å**3 (80 GPa).  A target pressure at least this large is more likely
#: a number meant in GPa or bar than one in ASE's unit: warned about.
UNLIKELY_PRESSURE = 0.5


def _checked_pressure(value):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise TypeError('pressure_au must be a number (eV/Å**3, e.g. '
                        f'1.0 * ase.units.GPa), got {value!r}') from None
    if not math.isfinite(value):
        raise ValueError(f'pressure_au must be finite (eV/Å**3), got '
                         f'{value!r}')
    if abs(value) >= UNLIKELY_PRESSURE:
        warnings.warn(
            f'pressure_au={value:g} eV/Å**3 is {value / units.GPa:.4g} GPa. '
            'pressure_au is in eV/Å**3, as for ASE\'s barostats: for '
            f'{value:g} GPa pass {value:g} * ase.units.GPa, for {value:g} bar '
            f'{value:g} * ase.units.bar.', UserWarning, stacklevel=3)
    return value


#: The thermostats: Langevin's friction and noise (the default) or Nosé's
#: chain (:mod:`~ase_reversible.md.npt.nose`).
THERMOSTATS = ('langevin', 'nose')


def checked_thermostat(thermostat, expected, name):
    """Refuse a ``thermostat`` that is not one of :data:`THERMOSTATS`, or
    one this class ``name`` (taking ``expected``) does not run."""
    if thermostat not in THERMOSTATS:
        raise ValueError(f"thermostat must be one of {THERMOSTATS}, got "
                         f'{thermostat!r}')
    if thermostat != expected:
        raise ValueError(
            f"{name} runs the {expected!r} thermostat, not {thermostat!r}: "
            "construct ReversibleIsotropicNPT or ReversibleNPT with "
            f"thermostat={thermostat!r} instead.")


def checked_settings(timestep, temperature_K, pressure_au, tdamp, pdamp,
                      energy_check, energy_tolerance):
    """``(timestep, (temperature_K, pressure_au, tdamp, pdamp),
    energy_check, energy_tolerance)``, each checked."""
    timestep = check_timestep(timestep)
    temperature_K = checked_positive(temperature_K, 'temperature_K', 'K')
    pressure_au = _checked_pressure(pressure_au)
    tdamp = checked_positive(tdamp, 'tdamp', 'ASE time units, e.g. '
                             '100 * ase.units.fs')
    pdamp = checked_positive(pdamp, 'pdamp', 'ASE time units, e.g. '
                             '1000 * ase.units.fs')
    energy_check, energy_tolerance = check_energy_watch(
        energy_check, energy_tolerance)
    return (timestep, (temperature_K, pressure_au, tdamp, pdamp),
            energy_check, energy_tolerance)


def _refuse_cell(atoms, name):
    from ase import Atoms
    if not isinstance(atoms, Atoms):
        return  # admit() refuses it with its own message
    if not atoms.pbc.all():
        raise ValueError(
            f'{name} needs atoms periodic in all three '
            f'directions (pbc is {atoms.pbc.tolist()}): the pressure is '
            'that of a periodic cell. Set atoms.pbc = True with a cell '
            'around the atoms, or use ReversibleLangevin for a cluster.')
    if not cell_volume(atoms.cell.array) > 0:
        raise ValueError(f'{name} needs a cell of positive '
                         f'volume, got {atoms.cell.array.tolist()}.')


def _refuse_constraints(atoms, name='ReversibleIsotropicNPT'):
    if len(getattr(atoms, 'constraints', ())):
        raise UnsupportedConstraintError(
            f'{name} supports no constraints yet (got '
            f'{", ".join(type(c).__name__ for c in atoms.constraints)}): '
            'a constraint would have to move with the cell. Remove them '
            '(del atoms.constraints).')


def _refuse_stressless(atoms, name='ReversibleIsotropicNPT'):
    try:
        stress = atoms.get_stress(voigt=True, apply_constraint=False)
    except (PropertyNotImplementedError, NotImplementedError,
            AttributeError) as error:
        raise ValueError(
            f'{name} needs the stress, and '
            f'{type(atoms.calc).__name__} does not give it ({error!r}): '
            'the piston is pushed by it. Use a calculator that computes '
            'the stress (ASE EMT or LennardJones, asap3, '
            'ase_reversible.LennardJones).') from None
    if np.shape(stress) != (6,) or not np.isfinite(stress).all():
        raise ValueError(f'The stress of {type(atoms.calc).__name__} is not '
                         f'six finite numbers: {stress!r}.')


def _starts_at_rest(system, section):
    """Whether the run holds the atoms' total momentum at exactly zero: a
    resumed run as its record says (a record without the mark is of a
    run that did not), a new one if its net momentum is zero but for
    rounding -- at most one count of ``pi`` per atom in each component,
    what snapping momenta with a zero float sum to the grid leaves (ASE's
    ``Stationary``, momenta absent or zero).  A thermal start that is not
    at rest has a net momentum of about ``sqrt(N m kT)``, far above that,
    and keeps the bits it had before the balance existed."""
    if section is not None:
        return section.get('zero_momentum') is True
    net_c = np.abs(system.p.ints.sum(axis=0))
    return bool(np.all(net_c <= system.p.ints.shape[0]))


def _fixed_setting(name, attribute, doc):
    """A property that shows the system's ``attribute`` as ``name`` and
    refuses assignment (the setting is fixed at construction)."""
    def show(self):
        return getattr(self.system, attribute)

    def refuse(self, value):
        fixed(name)
    show.__doc__ = doc
    return property(show, refuse)
