/* A force as a function of the positions alone, for the few atoms whose
   kick the guard flags (a part of fix reversible/nve).

   LAMMPS sums an atom's pair terms in neighbour-list order and adds the
   terms other ranks computed for it (newton) in communication order, so
   the last bits of a force depend on the decomposition and on history.
   Here an owned atom's force is summed from its own terms only, each from
   the pair style's per-pair function (Pair::single) and the bond style's
   (Bond::single), in the order of the partner's offset: every quantity
   it reads (the offsets, exact on the position grid, and the types) is
   the same on any decomposition and any numbering of the atoms, so the
   sum is too.  Styles without such a per-pair form (many-body
   pair styles, kspace, angles and higher, fixes that change forces) are
   named by reason() and keep the global setup.  */

#ifndef LMP_REVERSIBLE_CANONICAL_FORCE_H
#define LMP_REVERSIBLE_CANONICAL_FORCE_H

#include "pointers.h"

#include <vector>

namespace LAMMPS_NS {

class CanonicalForce : protected Pointers {
 public:
  // Why a run cannot recompute locally (LOCAL if it can): the values the
  // driver reads from compute_vector and names in its message.
  enum Reason {
    LOCAL = 0,
    NO_PAIR = 1,
    KSPACE = 2,
    MANYBODY = 3,
    NO_SINGLE = 4,
    ANGLES = 5,
    TEMPLATE = 6,
    FORCE_FIX = 7
  };

  CanonicalForce(class LAMMPS *);
  // Decided at init, the same on every rank: the styles are global.
  int reason(const class Fix *self) const;
  // Whether bonds stored on other atoms must be sent to the ghosts first.
  bool needs_topology() const;

  // At a step with flagged atoms: bin every owned and ghost atom.
  void bin();
  // The force on owned atom i, summed canonically.
  void compute(int i, double *out);

  // The bonds of every owned atom (count, then type and partner ID), for
  // the fix's forward communication to the ghosts.
  void fill_owned_topology();
  int topology_size() const;
  int pack_topology(int n, int *list, double *buf);
  void unpack_topology(int n, int first, double *buf);

 private:
  struct Term {
    double key[3];    // the offset x_i - x_j: unique, exact
    int j;
    double rsq;
    int level;        // special-list level (0: none)
  };
  double lo[3], width;
  int nbins[3];
  std::vector<int> bin_start, bin_atoms;
  std::vector<Term> terms;
  int bonds_per_atom;
  std::vector<double> topology;    // per atom: count, then (type, ID) pairs

  int special_level(int i, int j) const;
  void add_bonds(int i, double *out);
};

}    // namespace LAMMPS_NS

#endif
