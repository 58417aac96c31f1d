"""Rigid molecules as exact rigid bodies.

Which atoms form them (:mod:`ase_reversible.md.rigid.layout`, from ASE's
FixBondLengths and FixLinearTriatomic), the system of free atoms and
bodies with its drift and kick (:mod:`ase_reversible.md.rigid.system`)
and their adjoint rules (:mod:`ase_reversible.md.rigid.adjoint`); the
rotations by rounded shears are :mod:`ase_reversible.core.rigid`'s.
"""
