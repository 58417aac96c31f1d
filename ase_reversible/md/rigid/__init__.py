"""Rigid molecules as exact rigid bodies: which atoms form them
(:mod:`.layout`, from ASE's FixBondLengths and FixLinearTriatomic) and the
system of free atoms and bodies with its drift and kick (:mod:`.system`);
the rotations by rounded shears are :mod:`ase_reversible.core.rigid`'s."""
