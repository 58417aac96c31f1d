/* A force as a function of the positions alone: see the header.

   Built with -ffp-contract=off and without -ffast-math, as the fix: the
   sums below must round the same on every rank that computes them. */

#include "canonical_force.h"

#include "atom.h"
#include "bond.h"
#include "domain.h"
#include "error.h"
#include "fix.h"
#include "force.h"
#include "modify.h"
#include "pair.h"

#include <algorithm>
#include <cmath>

using namespace LAMMPS_NS;

CanonicalForce::CanonicalForce(LAMMPS *lmp) :
    Pointers(lmp), lo{0.0, 0.0, 0.0}, width(1.0), nbins{1, 1, 1}, bonds_per_atom(0)
{
}

int CanonicalForce::reason(const Fix *self) const
{
  Pair *pair = force->pair;
  if (!pair) return NO_PAIR;
  if (force->kspace) return KSPACE;
  if (pair->manybody_flag) return MANYBODY;
  if (!pair->single_enable) return NO_SINGLE;
  if (atom->nangles > 0 || atom->ndihedrals > 0 || atom->nimpropers > 0) return ANGLES;
  if (atom->molecular == Atom::TEMPLATE) return TEMPLATE;
  // A fix that adds to or sets forces after the pair style (setforce,
  // addforce, ...) would have to be replayed on the recomputed force.
  for (int n = 0; n < modify->nfix; n++) {
    if (modify->fix[n] == self) continue;
    if (modify->fmask[n] & (FixConst::POST_FORCE | FixConst::PRE_REVERSE)) return FORCE_FIX;
  }
  return LOCAL;
}

bool CanonicalForce::needs_topology() const
{
  return force->bond && atom->nbonds > 0 && force->newton_bond;
}

/* Bins of the pair style's largest cutoff over every owned and ghost
   atom: an atom's partners within the cutoff lie in the 27 bins around
   its own.  The ghosts reach the neighbour cutoff beyond the subdomain,
   so every partner of an owned atom is here. */

void CanonicalForce::bin()
{
  double **x = atom->x;
  const int nall = atom->nlocal + atom->nghost;
  double hi[3];
  for (int d = 0; d < 3; d++) lo[d] = hi[d] = nall ? x[0][d] : 0.0;
  for (int i = 1; i < nall; i++) {
    for (int d = 0; d < 3; d++) {
      lo[d] = std::min(lo[d], x[i][d]);
      hi[d] = std::max(hi[d], x[i][d]);
    }
  }
  width = force->pair->cutforce > 0.0 ? force->pair->cutforce : 1.0;
  // At most a few bins per atom: a short cutoff in a sparse box would
  // otherwise ask for more bins than memory.
  for (;;) {
    double cells = 1.0;
    for (int d = 0; d < 3; d++) {
      nbins[d] = 1 + static_cast<int>((hi[d] - lo[d]) / width);
      cells *= nbins[d];
    }
    if (cells <= 8.0 * nall + 27.0) break;
    width *= 2.0;
  }
  const size_t ncells = static_cast<size_t>(nbins[0]) * nbins[1] * nbins[2];
  bin_start.assign(ncells + 1, 0);
  bin_atoms.resize(nall);
  std::vector<int> cell(nall);
  for (int i = 0; i < nall; i++) {
    int c[3];
    for (int d = 0; d < 3; d++)
      c[d] = std::min(static_cast<int>((x[i][d] - lo[d]) / width), nbins[d] - 1);
    cell[i] = (c[2] * nbins[1] + c[1]) * nbins[0] + c[0];
    bin_start[cell[i] + 1]++;
  }
  for (size_t c = 0; c < ncells; c++) bin_start[c + 1] += bin_start[c];
  std::vector<int> next(bin_start.begin(), bin_start.end() - 1);
  for (int i = 0; i < nall; i++) bin_atoms[next[cell[i]]++] = i;
}

/* The special-list level of the pair (i, j): 1, 2 or 3 for a 1-2, 1-3 or
   1-4 partner, 0 for none, as LAMMPS's neighbour lists find it. */

int CanonicalForce::special_level(int i, int j) const
{
  if (atom->molecular == Atom::ATOMIC || !atom->special) return 0;
  const tagint *special = atom->special[i];
  const int *count = atom->nspecial[i];
  const tagint partner = atom->tag[j];
  for (int m = 0; m < count[2]; m++) {
    if (special[m] != partner) continue;
    return m < count[0] ? 1 : (m < count[1] ? 2 : 3);
  }
  return 0;
}

void CanonicalForce::compute(int i, double *out)
{
  double **x = atom->x;
  const int *type = atom->type;
  Pair *pair = force->pair;
  double **cutsq = pair->cutsq;
  const int itype = type[i];
  int c[3];
  for (int d = 0; d < 3; d++)
    c[d] = std::min(static_cast<int>((x[i][d] - lo[d]) / width), nbins[d] - 1);
  terms.clear();
  for (int dz = -1; dz <= 1; dz++) {
    const int cz = c[2] + dz;
    if (cz < 0 || cz >= nbins[2]) continue;
    for (int dy = -1; dy <= 1; dy++) {
      const int cy = c[1] + dy;
      if (cy < 0 || cy >= nbins[1]) continue;
      for (int dx = -1; dx <= 1; dx++) {
        const int cx = c[0] + dx;
        if (cx < 0 || cx >= nbins[0]) continue;
        const int cell = (cz * nbins[1] + cy) * nbins[0] + cx;
        for (int n = bin_start[cell]; n < bin_start[cell + 1]; n++) {
          const int j = bin_atoms[n];
          if (j == i) continue;
          const double delx = x[i][0] - x[j][0];
          const double dely = x[i][1] - x[j][1];
          const double delz = x[i][2] - x[j][2];
          const double rsq = delx * delx + dely * dely + delz * delz;
          if (!(rsq < cutsq[itype][type[j]])) continue;
          terms.push_back({{delx, dely, delz}, j, rsq, special_level(i, j)});
        }
      }
    }
  }
  std::sort(terms.begin(), terms.end(), [](const Term &a, const Term &b) {
    return std::lexicographical_compare(a.key, a.key + 3, b.key, b.key + 3);
  });
  double sum[3] = {0.0, 0.0, 0.0};
  for (const Term &t : terms) {
    double factor_lj = 1.0, factor_coul = 1.0;
    // A special partner beyond half the box is a plain one, as LAMMPS's
    // lists take it.
    if (t.level > 0 && !domain->minimum_image_check(t.key[0], t.key[1], t.key[2])) {
      factor_lj = force->special_lj[t.level];
      factor_coul = force->special_coul[t.level];
    }
    double fpair = 0.0;
    pair->single(i, t.j, itype, type[t.j], t.rsq, factor_coul, factor_lj, fpair);
    for (int d = 0; d < 3; d++) sum[d] += t.key[d] * fpair;
  }
  double bonded[3] = {0.0, 0.0, 0.0};
  add_bonds(i, bonded);
  for (int d = 0; d < 3; d++) out[d] = sum[d] + bonded[d];
}

/* The bond terms of owned atom i, in the order of the partner's offset
   (then of the bond's type).
   With newton_bond a bond is stored on one of its atoms only, so those
   stored on the partner come from the forwarded topology. */

void CanonicalForce::add_bonds(int i, double *out)
{
  if (!force->bond || atom->nbonds == 0) return;
  struct Bond {
    double partner, type, storer, slot;
  };
  std::vector<Bond> bonds;
  const tagint *tag = atom->tag;
  for (int m = 0; m < atom->num_bond[i]; m++) {
    if (atom->bond_type[i][m] <= 0) continue;    // broken or turned off
    bonds.push_back({static_cast<double>(atom->bond_atom[i][m]),
                     static_cast<double>(atom->bond_type[i][m]), static_cast<double>(tag[i]),
                     static_cast<double>(m)});
  }
  if (needs_topology()) {
    // Every image of an atom storing a bond to i, within the bond's reach.
    const int stride = 1 + 2 * bonds_per_atom;
    const int nall = atom->nlocal + atom->nghost;
    const double me = static_cast<double>(tag[i]);
    for (int j = 0; j < nall; j++) {
      const double *row = &topology[static_cast<size_t>(j) * stride];
      for (int m = 0; m < static_cast<int>(row[0]); m++) {
        if (row[2 + 2 * m] != me || row[1 + 2 * m] <= 0.0) continue;
        bonds.push_back({static_cast<double>(tag[j]), row[1 + 2 * m],
                         static_cast<double>(tag[j]), static_cast<double>(m)});
      }
    }
  }
  std::sort(bonds.begin(), bonds.end(), [](const Bond &a, const Bond &b) {
    if (a.partner != b.partner) return a.partner < b.partner;
    if (a.type != b.type) return a.type < b.type;
    if (a.storer != b.storer) return a.storer < b.storer;
    return a.slot < b.slot;
  });
  bonds.erase(std::unique(bonds.begin(), bonds.end(),
                          [](const Bond &a, const Bond &b) {
                            return a.partner == b.partner && a.type == b.type &&
                                a.storer == b.storer && a.slot == b.slot;
                          }),
              bonds.end());
  double **x = atom->x;
  struct Term {
    double key[4];    // the offset, then the type
    int j;
  };
  std::vector<Term> terms;
  for (const Bond &b : bonds) {
    const int near = atom->map(static_cast<tagint>(b.partner));
    if (near < 0)
      error->one(FLERR, "fix reversible: bond partner {} of atom {} is missing",
                 static_cast<tagint>(b.partner), tag[i]);
    const int j = domain->closest_image(i, near);
    terms.push_back({{x[i][0] - x[j][0], x[i][1] - x[j][1], x[i][2] - x[j][2], b.type}, j});
  }
  std::sort(terms.begin(), terms.end(), [](const Term &a, const Term &b) {
    return std::lexicographical_compare(a.key, a.key + 4, b.key, b.key + 4);
  });
  for (const Term &t : terms) {
    const double rsq = t.key[0] * t.key[0] + t.key[1] * t.key[1] + t.key[2] * t.key[2];
    double fbond = 0.0;
    force->bond->single(static_cast<int>(t.key[3]), rsq, i, t.j, fbond);
    for (int d = 0; d < 3; d++) out[d] += t.key[d] * fbond;
  }
}

int CanonicalForce::topology_size() const
{
  return 1 + 2 * bonds_per_atom;
}

void CanonicalForce::fill_owned_topology()
{
  bonds_per_atom = atom->bond_per_atom;
  const int stride = topology_size();
  topology.assign(static_cast<size_t>(atom->nmax) * stride, 0.0);
  for (int i = 0; i < atom->nlocal; i++) {
    double *row = &topology[static_cast<size_t>(i) * stride];
    row[0] = atom->num_bond[i];
    for (int m = 0; m < atom->num_bond[i]; m++) {
      row[1 + 2 * m] = atom->bond_type[i][m];
      row[2 + 2 * m] = static_cast<double>(atom->bond_atom[i][m]);
    }
  }
}

int CanonicalForce::pack_topology(int n, int *list, double *buf)
{
  const int stride = topology_size();
  int m = 0;
  for (int k = 0; k < n; k++) {
    const double *row = &topology[static_cast<size_t>(list[k]) * stride];
    for (int s = 0; s < stride; s++) buf[m++] = row[s];
  }
  return m;
}

void CanonicalForce::unpack_topology(int n, int first, double *buf)
{
  const int stride = topology_size();
  int m = 0;
  for (int k = first; k < first + n; k++) {
    double *row = &topology[static_cast<size_t>(k) * stride];
    for (int s = 0; s < stride; s++) row[s] = buf[m++];
  }
}
