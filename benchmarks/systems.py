"""Systems and calculators only the benchmarks use (the standard ones are
``ase_reversible.app.systems``'s)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import asap3
import numpy as np
from ase import Atoms, units
from ase.build import bulk
from ase.calculators.calculator import Calculator, all_changes
from ase.calculators.emt import EMT
from ase.constraints import FixCom
from ase.md.langevin import Langevin
from ase.md.nose_hoover_chain import IsotropicMTKNPT, NoseHooverChainNVT
from ase.md.velocitydistribution import Stationary
from ase.md.verlet import VelocityVerlet
from harness import Settings

from ase_reversible import (ReversibleIsotropicNPT, ReversibleLangevin,
                            ReversibleNose, ReversibleVerlet)
from ase_reversible.app.systems import (AR_EPSILON, AR_RC, AR_SIGMA,
                                        argon_bulk, argon_lj, copper_bulk,
                                        thermalize)

#: Copper's lattice constant in ase.build.bulk, Å, and its bond length.
CU_LATTICE = 3.61
CU_BOND = CU_LATTICE / np.sqrt(2)

#: RGL (Gupta) parameters for copper of Cleri and Rosato, Phys. Rev. B 48,
#: 22 (1993), and the lattice constant they imply (sqrt(2) * r0).
CU_RGL = dict(p=10.960, q=2.278, a=0.0855, xi=1.224, r0=2.556)
CU_RGL_LATTICE = 3.615


def asap3_argon_lj(cutoff=AR_RC):
    """A constructor of asap3's LennardJones with the argon parameters: a
    partial, as asap3 calculators cannot be pickled (savings.py hands it to
    worker processes)."""
    return functools.partial(asap3.LennardJones, [18], [AR_EPSILON],
                             [AR_SIGMA], rCut=cutoff, modified=True)


def copper_rgl():
    return asap3.RGL(['Cu'], **CU_RGL)


#: Fresh calculators by the labels the tables use.
CALCULATORS = {
    'ASE LJ': argon_lj,
    'asap3 LJ': asap3_argon_lj(),
    'ASE EMT': EMT,
    'asap3 EMT': asap3.EMT,
}


def rgl_copper_crystal(repeat, temperature_K, seed=0):
    """Periodic fcc copper at the RGL potential's own lattice constant."""
    atoms = bulk('Cu', 'fcc', a=CU_RGL_LATTICE, cubic=True) * repeat
    return thermalize(atoms, temperature_K, seed)


def argon_fluid(n_atoms, cell_length, temperature_K, seed=0):
    """``n_atoms`` on a simple cubic lattice in a periodic cube."""
    k = int(np.ceil(n_atoms ** (1 / 3)))
    sites = (np.indices((k, k, k)).reshape(3, -1).T[:n_atoms] + 0.5) / k
    atoms = Atoms(f'Ar{n_atoms}', scaled_positions=sites,
                  cell=[cell_length] * 3, pbc=True)
    return thermalize(atoms, temperature_K, seed)


def pair(symbol, gap):
    """Two atoms at rest ``gap`` Å apart in 10 Å of vacuum."""
    atoms = Atoms(symbol * 2, positions=[(0, 0, 0), (gap, 0, 0)])
    atoms.center(vacuum=10.0)
    return atoms


def copper_bulk_contact(fraction):
    """Perfect Cu bulk (108 atoms) with atom 0 moved towards a neighbour
    until they are ``fraction`` of the bond length apart."""
    atoms = bulk('Cu', cubic=True) * (3, 3, 3)
    vectors = atoms.get_distances(0, range(1, len(atoms)), mic=True,
                                  vector=True)
    nearest = vectors[np.argmin(np.linalg.norm(vectors, axis=1))]
    atoms.positions[0] += (1 - fraction) * nearest
    return atoms


class CachedForces(Calculator):
    """A calculator whose force call costs next to nothing: zero forces and
    energy, "computed" (copied) again whenever the positions are not
    bitwise those of the last call, a cache as cheap to check as asap3's
    (ASE's ``check_state`` would bury the integrators' work at ~0.2 ms a
    call).  The atoms fly freely, the energy is exactly conserved; declared
    pure for ReversibleVerlet's ``force_purity='auto'``."""

    implemented_properties = ('energy', 'forces')
    forces_are_pure = True

    def __init__(self, n_atoms):
        super().__init__()
        self._fixed = {'energy': 0.0, 'forces': np.zeros((n_atoms, 3))}
        self._x_nc = None  # positions of the last calculation

    def check_state(self, atoms, tol=1e-15):
        x_nc = atoms.arrays['positions']
        if (self._x_nc is not None and x_nc.shape == self._x_nc.shape
                and x_nc.tobytes() == self._x_nc.tobytes()):
            return []
        return ['positions']

    def calculate(self, atoms=None, properties=('forces',),
                  system_changes=all_changes):
        self._x_nc = atoms.arrays['positions'].copy()
        self.results = dict(self._fixed)


class ResultCache:
    """An asap3 potential behind a cache of its last results: asap3's
    LennardJones recomputes at unchanged positions for a free cluster, and
    ASE's VelocityVerlet asks three times a step."""

    def __init__(self, inner):
        self.inner = inner
        self._mirror = None  # atoms carrying the inner calculator
        # Forces and energy are separate computations, each only when asked.
        self._forces_at = self._energy_at = None
        self._f_nc = self._energy = None

    def _move(self, atoms):
        if self._mirror is None or len(self._mirror) != len(atoms):
            self._mirror = atoms.copy()
            self._mirror.calc = self.inner
        self._mirror.positions = atoms.positions

    def get_forces(self, atoms):
        x_nc = atoms.positions
        if self._forces_at is None or not np.array_equal(x_nc,
                                                         self._forces_at):
            self._move(atoms)
            self._f_nc = self._mirror.get_forces()
            self._forces_at = x_nc.copy()
        return self._f_nc.copy()

    def get_potential_energy(self, atoms, force_consistent=False):
        x_nc = atoms.positions
        if self._energy_at is None or not np.array_equal(x_nc,
                                                         self._energy_at):
            self._move(atoms)
            self._energy = self._mirror.get_potential_energy()
            self._energy_at = x_nc.copy()
        return self._energy

# -- the thermostats' systems and integrators (thermostat, nose, studies) --

@dataclass(frozen=True)
class ThermostatSystem:
    label: str
    calculator: str  # key of CALCULATORS
    build: Callable  # (repeat, temperature_K) -> atoms
    repeat: tuple
    temperature_K: float
    timestep_fs: float
    force_noise: float = None  # eV/Å, for ReversibleBussi

    def calculator_instance(self):
        return CALCULATORS[self.calculator]()

    def atoms(self, repeat=None):
        atoms = self.build(repeat or self.repeat, self.temperature_K)
        Stationary(atoms)  # every thermostat keeps the centre of mass at rest
        atoms.calc = self.calculator_instance()
        return atoms


THERMOSTAT_SYSTEMS = (
    ThermostatSystem('Ar fcc', 'asap3 LJ', argon_bulk, (4, 4, 4), 80.0, 10.0),
    ThermostatSystem('Cu fcc', 'asap3 EMT', copper_bulk, (4, 4, 4), 600.0,
                     5.0),
)
#: Interleaved cost rounds of the thermostats, by quick.
THERMOSTAT_SPEED = {
    False: Settings(rounds=9, block_seconds=0.5, min_steps=2, max_steps=2000,
                    warmup_steps=5),
    True: Settings(rounds=3, block_seconds=0.05, min_steps=2, max_steps=200,
                   warmup_steps=2)}
#: Friction of every Langevin run, 1 / fs, and the seed of its noise.
FRICTION_PER_FS = 0.01
SEED = 7
#: Nosé's tdamp in time steps, and the factor of the temperature its
#: momenta are drawn at on the bare lattice (equipartition halves it).
TDAMP_STEPS = 40
START_FACTOR = 2.0


def reversible_langevin(atoms, system):
    return ReversibleLangevin(atoms, system.timestep_fs * units.fs,
                              system.temperature_K,
                              FRICTION_PER_FS / units.fs, fixcm=True,
                              seed=SEED)


def ase_langevin(atoms, system):
    """ASE's Langevin with the centre of mass held by FixCom."""
    atoms.set_constraint(FixCom())
    return Langevin(atoms, system.timestep_fs * units.fs,
                    temperature_K=system.temperature_K,
                    friction=FRICTION_PER_FS / units.fs, fixcm=False,
                    rng=np.random.default_rng(SEED))


def tdamp(system):
    return TDAMP_STEPS * system.timestep_fs * units.fs


def reversible_nose(atoms, system, tchain=1):
    # The recipe for canonical frames: the centre held at rest by FixCom,
    # so N_f = 3N - 3 and the internal motion is at the target (without
    # it ReversibleNose, as ASE's class, thermostats 3N).
    atoms.set_constraint(FixCom())
    return ReversibleNose(atoms, system.timestep_fs * units.fs,
                          system.temperature_K, tdamp(system), tchain=tchain)


def ase_nose_hoover_chain(atoms, system):
    return NoseHooverChainNVT(atoms, system.timestep_fs * units.fs,
                              temperature_K=system.temperature_K,
                              tdamp=tdamp(system))


THERMOSTATS = {
    'reversible_langevin': reversible_langevin,
    'ase_langevin': ase_langevin,
    'reversible_nose': reversible_nose,
    'ase_nose_hoover_chain': ase_nose_hoover_chain,
    'velocity_verlet': lambda atoms, system: VelocityVerlet(
        atoms, system.timestep_fs * units.fs),
    'reversible_verlet': lambda atoms, system: ReversibleVerlet(
        atoms, system.timestep_fs * units.fs),
}


def drawn_hot(build, **options):
    """``build`` with the momenta drawn at ``START_FACTOR`` times the
    temperature it is given."""
    def built(repeat, temperature_K):
        return build(repeat, START_FACTOR * temperature_K, **options)
    return built


#: THERMOSTAT_SYSTEMS at 5 fs for Nosé, on the bare lattice, drawn hot.
NOSE_SYSTEMS = (
    ThermostatSystem('Ar fcc', 'asap3 LJ', drawn_hot(argon_bulk), (4, 4, 4),
                     80.0, 5.0),
    ThermostatSystem('Cu fcc', 'asap3 EMT', drawn_hot(copper_bulk, rattle=0),
                     (4, 4, 4), 600.0, 5.0),
)


# -- the NPT cases (npt_sampling, npt_cost) ------------------------------------

#: Argon's Lennard-Jones parameters of the NPT cases (eV, Å), its cut-off
#: and the reduced density rho sigma**3 of its start (the liquid's).
NPT_AR_EPSILON, NPT_AR_SIGMA = 0.0103, 3.405
NPT_AR_CUTOFF = 3 * NPT_AR_SIGMA
NPT_AR_REDUCED_DENSITY = 0.73
#: Seed of the momenta and of the reversible thermostat's noise.
NPT_SEED = 7
#: The thermostat's and barostat's times in time steps.
TDAMP_NPT_STEPS, PDAMP_NPT_STEPS = 100, 1000


def npt_copper(repeat):
    """Periodic fcc copper at ase.build's lattice constant, no momenta."""
    return bulk('Cu', 'fcc', cubic=True) * repeat


def npt_argon(repeat):
    """Argon on fcc sites at the liquid's reduced density."""
    lattice = (4 / (NPT_AR_REDUCED_DENSITY / NPT_AR_SIGMA**3)) ** (1 / 3)
    return bulk('Ar', 'fcc', a=lattice, cubic=True) * repeat


NPT_BUILDERS = {
    'copper': (npt_copper, lambda: ('asap3 EMT', asap3.EMT())),
    'argon': (npt_argon, lambda: ('asap3 LJ', asap3.LennardJones(
        [18], [NPT_AR_EPSILON], [NPT_AR_SIGMA], rCut=NPT_AR_CUTOFF,
        modified=True)))}


@dataclass(frozen=True)
class NptCase:
    label: str
    system: str  # key of NPT_BUILDERS
    repeat: tuple
    temperature_K: float
    timestep_fs: float
    pressure_GPa: float
    round_trip: bool = True  # the reversible run goes back too
    #: force_noise of ReversibleIsotropicNPT, eV/Å (None: its default).
    force_noise: float = None

    @property
    def timestep(self):
        return self.timestep_fs * units.fs

    @property
    def pressure_au(self):
        return self.pressure_GPa * units.GPa

    def atoms(self, repeat=None):
        """(the calculator's label, the shared start with a fresh one)."""
        build, calculator = NPT_BUILDERS[self.system]
        atoms = thermalize(build(repeat or self.repeat), self.temperature_K,
                           NPT_SEED)
        # ASE's chain thermostat keeps a net momentum of the start: the
        # centre of mass of Cu 256 drifted 140 Å in 40,000 steps.
        Stationary(atoms)
        name, atoms.calc = calculator()
        return name, atoms


NPT_CASES = (
    NptCase('Cu fcc, 0 GPa', 'copper', (4, 4, 4), 300.0, 5.0, 0.0),
    NptCase('Cu fcc, 1 GPa', 'copper', (4, 4, 4), 300.0, 5.0, 1.0,
            round_trip=False),
    # asap3's LennardJones in a moving cell: a 10^5-step run saw 2.76e-14
    # eV/Å of force noise against a bound of 3e-14 and advised 3.4e-13.
    NptCase('Ar liquid, 50 bar', 'argon', (4, 4, 4), 100.0, 10.0, 50e-4,
            force_noise=3.4e-13),
    # Half the time step: what of a difference at 5 fs is time-step error.
    NptCase('Cu fcc, 0 GPa, 2.5 fs', 'copper', (4, 4, 4), 300.0, 2.5, 0.0,
            round_trip=False),
)


def reversible_npt(atoms, case):
    h = case.timestep
    return ReversibleIsotropicNPT(
        atoms, h, case.temperature_K, case.pressure_au, TDAMP_NPT_STEPS * h,
        PDAMP_NPT_STEPS * h, seed=NPT_SEED, force_noise=case.force_noise)


def ase_npt(atoms, case):
    h = case.timestep
    return IsotropicMTKNPT(atoms, h, case.temperature_K, case.pressure_au,
                           TDAMP_NPT_STEPS * h, PDAMP_NPT_STEPS * h)


NPT_INTEGRATORS = {'reversible_npt': reversible_npt, 'ase_npt': ase_npt}
