/* Exact, reversible velocity Verlet as a LAMMPS fix: see the header.

   Build without -ffast-math and with -ffp-contract=off: every product
   below must be rounded on its own, as numpy rounds it, or the kicks
   differ from the Python path's in the last bit. */

#include "fix_reversible_nve.h"

#include "atom.h"
#include "comm.h"
#include "domain.h"
#include "error.h"
#include "timer.h"
#include "update.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <string>

using namespace LAMMPS_NS;
using namespace FixConst;

namespace {

// 1.5 * 2^52: adding and subtracting it rounds |y| < 2^51 to an integer,
// ties to even, in two inlined additions (nearbyint is a libm call in a
// generic build).  copysign keeps rint's -0.0 for small negative y, so
// the kicks and the velocities they leave are the Python path's to the
// bit, zeros' signs included.
constexpr double MAGIC = 6755399441055744.0;
// Kicks must stay below LIMIT / 4 = 2^51 quanta (ase_reversible.core.codec).
constexpr double KICK_LIMIT = 2251799813685248.0;

inline double round_odd(double y)
{
  return std::copysign((y + MAGIC) - MAGIC, y);
}

}    // namespace

FixReversibleNVE::FixReversibleNVE(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), mode(START), flag(0), forced_timeout(0), qv(0.0),
    force_noise(0.0), extent_factor(1.0), sort_bin(0.0), canonical(false), scale_min(0.0),
    scale_max(0.0), uniform(true), kick_index(-1), next_index(-1), parity(0),
    canonical_force(nullptr), local_reason(CanonicalForce::NO_PAIR), last_force(0.0),
    local_steps(0), local_atoms(0.0), local_atoms_all(0.0), local_seconds(0.0), local_seconds_all(0.0), local_noise(0.0), local_bound(INFINITY), run_force(0.0),
    run_force_all(0.0), observed(0), observed_noise(0.0), observed_bound(0.0), noisy_bound(0.0)
{
  if (igroup != 0)
    error->all(FLERR, "fix {} acts on group all: exact runs move every atom", style);
  time_integrate = 1;
  vector_flag = 1;
  size_vector = 16;
  global_freq = 1;
  extvector = 0;

  const int ntypes = atom->ntypes;
  type_scale.assign(ntypes + 1, 0.0);
  std::string kick, next;
  int iarg = 3;
  while (iarg < narg) {
    const std::string key = arg[iarg];
    if (key == "scale") {
      if (iarg + ntypes >= narg)
        error->all(FLERR, "fix {} scale needs one value per atom type ({})", style, ntypes);
      for (int t = 1; t <= ntypes; t++)
        type_scale[t] = utils::numeric(FLERR, arg[iarg + t], false, lmp);
      iarg += ntypes + 1;
      continue;
    }
    if (iarg + 1 >= narg) error->all(FLERR, "fix {} keyword {} needs a value", style, key);
    const char *value = arg[iarg + 1];
    if (key == "kick") kick = value;
    else if (key == "next") next = value;
    else if (key == "velocity_quantum") qv = utils::numeric(FLERR, value, false, lmp);
    else if (key == "force_noise") force_noise = utils::numeric(FLERR, value, false, lmp);
    else if (key == "extent_factor") extent_factor = utils::numeric(FLERR, value, false, lmp);
    else if (key == "sort_bin") sort_bin = utils::numeric(FLERR, value, false, lmp);
    else if (key == "mode") set_mode(value);
    else error->all(FLERR, "fix {}: unknown keyword {}", style, key);
    iarg += 2;
  }
  if (kick.empty()) error->all(FLERR, "fix {} needs kick NAME (a d2_ property/atom of 3 columns)", style);
  int is_double, cols;
  kick_index = atom->find_custom(kick.c_str(), is_double, cols);
  if (kick_index < 0 || is_double != 1 || cols != 3)
    error->all(FLERR, "fix {}: no per-atom array d2_{} of 3 columns (fix property/atom)", style, kick);
  if (next.empty()) error->all(FLERR, "fix {} needs next NAME (a d2_ property/atom of 3 columns)", style);
  next_index = atom->find_custom(next.c_str(), is_double, cols);
  if (next_index < 0 || is_double != 1 || cols != 3 || next_index == kick_index)
    error->all(FLERR, "fix {}: no per-atom array d2_{} of 3 columns (fix property/atom)", style, next);
  canonical_force = new CanonicalForce(lmp);
  scale_min = scale_max = std::fabs(type_scale[1]);
  for (int t = 1; t <= ntypes; t++) {
    scale_min = std::min(scale_min, std::fabs(type_scale[t]));
    scale_max = std::max(scale_max, std::fabs(type_scale[t]));
    if (type_scale[t] != type_scale[1]) uniform = false;
  }
}

FixReversibleNVE::~FixReversibleNVE()
{
  delete canonical_force;
}

int FixReversibleNVE::setmask()
{
  // PRE_NEIGHBOR for setup_pre_neighbor only: pre_neighbor() is empty.
  return INITIAL_INTEGRATE | PRE_NEIGHBOR | POST_FORCE | POST_RUN;
}

void FixReversibleNVE::init()
{
  if (atom->rmass_flag)
    error->all(FLERR, "fix {} needs per-type masses, not per-atom ones", style);
  local_reason = canonical_force->reason(this);
  // Before Comm::init, which sizes its buffers from every fix's
  // comm_forward: the bonds sent to the ghosts at a step with flags.
  comm_forward = (local_reason == CanonicalForce::LOCAL && canonical_force->needs_topology())
      ? 1 + 2 * atom->bond_per_atom
      : 0;
}

void FixReversibleNVE::set_mode(const char *value)
{
  const std::string m = value;
  if (m == "start") mode = START;
  else if (m == "redo") mode = REDO;
  else if (m == "halted") mode = HALTED;
  else error->all(FLERR, "fix {} mode must be start, redo or halted, not {}", style, m);
}

int FixReversibleNVE::modify_param(int narg, char **arg)
{
  if (narg < 2) return 0;
  if (strcmp(arg[0], "mode") == 0) {
    set_mode(arg[1]);
    return 2;
  }
  if (strcmp(arg[0], "sort_bin") == 0) {
    sort_bin = utils::numeric(FLERR, arg[1], false, lmp);
    return 2;
  }
  return 0;
}

/* The kicks alternate between two per-atom arrays: a step writes its
   kicks beside the pending ones, which a step that fails must leave as
   they were (the driver undoes its drift with them), and the two swap
   once it is taken.  Each is fetched at each use: the arrays move when
   atoms are added to them. */

double **FixReversibleNVE::pending()
{
  return atom->darray[parity ? next_index : kick_index];
}

double **FixReversibleNVE::next_kicks()
{
  return atom->darray[parity ? kick_index : next_index];
}

void FixReversibleNVE::flip()
{
  parity = 1 - parity;
}

double **FixReversibleNVE::exact_velocity()
{
  return atom->v;
}

/* A setup whose forces the kick takes as clean (a start or a redo) puts
   every rank's atoms in a canonical order, a function of the positions
   alone: sorted into bins of sort_bin, small enough to hold one atom
   each, then (a stable sort) into LAMMPS's own coarser sort bins, whose
   order keeps the pair loops' memory locality.  The fine order alone, as
   the Python path leaves it, cost fix nve 4% per step (32,000 argon
   atoms).  Between exchange and borders is where LAMMPS sorts; here the
   ghosts already exist, so they are rebuilt. */

void FixReversibleNVE::setup_pre_neighbor()
{
  // Recomputed locally, kicks need no canonical order: LAMMPS's own sort
  // stands, as under fix nve.
  if (local_reason == CanonicalForce::LOCAL) {
    canonical = true;
    return;
  }
  if (mode != START && mode != REDO) return;
  const int user_freq = atom->sortfreq;
  const double user_bin = atom->userbinsize;
  const bigint next_sort = atom->nextsort;
  atom->sortfreq = 1;
  atom->userbinsize = sort_bin;
  atom->setup();
  atom->sort();
  canonical = sorted_canonically();
  atom->userbinsize = user_bin;
  atom->sortfreq = user_freq;
  if (user_freq > 0) {
    atom->setup();
    atom->sort();
  } else {
    atom->nextsort = next_sort;
  }
  // The ghosts as comm->exchange leaves them for borders: none, unmapped.
  if (atom->map_style != 0) atom->map_clear();
  atom->nghost = 0;
  comm->borders();
}

void FixReversibleNVE::setup(int vflag)
{
  flag = 0;
  observed = 0;
  run_force = 0.0;
  last_force = 0.0;
  local_steps = 0;
  local_atoms = 0.0;
  local_seconds = 0.0;
  // A rank without flagged atoms has no bound to give the least of.
  local_noise = 0.0;
  local_bound = INFINITY;
  post_force(vflag);
}

/* The first half-kick (left by the previous step) and the drift: dt v is
   a multiple of dt q_v, itself a multiple of the position quantum, so
   both sums are exact. */

void FixReversibleNVE::initial_integrate(int /*vflag*/)
{
  double **x = atom->x;
  double **v = atom->v;
  double **k = pending();
  const double dt = update->dt;
  const int nlocal = atom->nlocal;
  for (int i = 0; i < nlocal; i++) {
    for (int d = 0; d < 3; d++) {
      v[i][d] += k[i][d];
      x[i][d] += dt * v[i][d];
    }
  }
}

/* The kick from this step's forces, rounded odd to the velocity grid and
   guarded: the verdicts, and the kicks where none is flagged, are the
   Python path's (ReversibleLammps._callback).  One pass computes, judges,
   stores and applies them; a step that fails is taken back from the
   stored kicks.  An atom is flagged where a component lies within the
   guard's bound of a rounding boundary; the bound scales with this step's
   largest force, known at the end of the pass, so the pass keeps the
   atoms within a bound from the previous step's (doubled), and rescans
   in the rare step whose forces more than doubled. */

void FixReversibleNVE::post_force(int /*vflag*/)
{
  if (mode == HALTED) return;
  const int nlocal = atom->nlocal;
  double **f = atom->f;
  const int *type = atom->type;
  double **k = next_kicks();
  double **v = exact_velocity();
  const bool setup = (mode == START || mode == REDO);
  const bool applied = (mode != START);    // a start's kick is the next step's first
  const bool local = (local_reason == CanonicalForce::LOCAL);
  const double per_force = force_noise * extent_factor * scale_max;
  const double guess = per_force * std::max(1.0, 2.0 * last_force);
  const double candidate = 0.5 - guess;
  candidates.clear();
  double r_max = 0.0, deviation = 0.0, f_abs = 0.0;
  bool out_of_range = false;
  for (int i = 0; i < nlocal; i++) {
    const double s = type_scale[type[i]];
    double atom_deviation = 0.0;
    for (int d = 0; d < 3; d++) {
      const double y = f[i][d] * s;
      const double kq = round_odd(y);
      const double a = std::fabs(kq);
      if (!(a < KICK_LIMIT)) {    // also NaN: nothing of it is applied
        out_of_range = true;
        k[i][d] = 0.0;
        continue;
      }
      if (a > r_max) r_max = a;
      const double e = std::fabs(y - kq);
      if (e > atom_deviation) atom_deviation = e;
      if (!uniform) {
        const double fa = std::fabs(f[i][d]);
        if (fa > f_abs) f_abs = fa;
      }
      const double kv = kq * qv;
      k[i][d] = kv;
      if (applied) v[i][d] += kv;
    }
    if (atom_deviation > deviation) deviation = atom_deviation;
    if (atom_deviation > candidate) candidates.push_back(i);
  }
  // With one mass the largest kick bounds the largest force; with several
  // it would overstate it by the mass ratio.
  const double f_max = uniform ? (r_max + 0.5) / scale_min : f_abs;
  if (f_max > run_force) run_force = f_max;
  last_force = f_max;
  const double bound = per_force * std::max(1.0, f_max);
  int mine = 0;
  if (out_of_range) mine |= OUT_OF_RANGE;
  else if (deviation > 0.5 - bound) mine |= AMBIGUOUS;
  if (setup && !canonical) mine |= NOT_CANONICAL;
  const int verdict = reduce_verdict(mine);

  if (verdict & OUT_OF_RANGE) {
    // The pending kicks stay: the driver takes the drift back with them.
    if (applied)
      for (int i = 0; i < nlocal; i++)
        for (int d = 0; d < 3; d++) v[i][d] -= k[i][d];
    halt(OUT_OF_RANGE);
    return;
  }
  if (local) {
    const bool impure = (verdict & AMBIGUOUS) && recompute_flagged(bound, guess, applied);
    flip();
    if (setup) mode = STEP;
    after_kick();
    if (impure) halt(IMPURE);
    return;
  }
  if (setup) {
    if ((verdict & AMBIGUOUS) && (verdict & NOT_CANONICAL)) {
      // The clean forces may depend on history after all: take nothing,
      // and let the driver retry with finer bins.
      if (applied)
        for (int i = 0; i < nlocal; i++)
          for (int d = 0; d < 3; d++) v[i][d] -= k[i][d];
      double **p = pending();
      for (int i = 0; i < nlocal; i++) p[i][0] = p[i][1] = p[i][2] = 0.0;
      halt(NOT_CANONICAL);
      return;
    }
    if (mode == REDO) compare_with_noisy();
    flip();
    mode = STEP;
    after_kick();
    return;
  }
  flip();
  after_kick();
  if (verdict & AMBIGUOUS) {
    // Keep the run's forces, by atom ID, for the clean recomputation to
    // be compared with.
    std::vector<int> order(nlocal);
    std::iota(order.begin(), order.end(), 0);
    const tagint *tag = atom->tag;
    std::sort(order.begin(), order.end(), [tag](int a, int b) { return tag[a] < tag[b]; });
    noisy_tag.resize(nlocal);
    noisy_f.resize(3 * static_cast<size_t>(nlocal));
    for (int j = 0; j < nlocal; j++) {
      noisy_tag[j] = tag[order[j]];
      for (int d = 0; d < 3; d++) noisy_f[3 * j + d] = f[order[j]][d];
    }
    noisy_bound = bound;
    halt(AMBIGUOUS);
  }
}

/* The flagged atoms' kicks from their canonical forces, on the ranks
   that own them.  Every rank takes part (the ghosts' bonds may have to be
   sent, and the step ends with a collective), flagged atoms or not.  A
   recomputed force further from the run's than the guard's bound means
   the unflagged kicks may not be the canonical ones: returns true on
   every rank, and the run halts for the driver to raise. */

bool FixReversibleNVE::recompute_flagged(double bound, double guess, bool applied)
{
  const double started = MPI_Wtime();
  const int nlocal = atom->nlocal;
  double **f = atom->f;
  const int *type = atom->type;
  double **k = next_kicks();
  double **v = exact_velocity();
  if (bound > guess) {
    candidates.clear();
    for (int i = 0; i < nlocal; i++) candidates.push_back(i);
  }
  std::vector<int> flagged;
  for (int i : candidates) {
    const double s = type_scale[type[i]];
    double e = 0.0;
    for (int d = 0; d < 3; d++) {
      const double y = f[i][d] * s;
      e = std::max(e, std::fabs(y - round_odd(y)));
    }
    if (e > 0.5 - bound) flagged.push_back(i);
  }
  if (canonical_force->needs_topology()) {
    canonical_force->fill_owned_topology();
    comm->forward_comm(this);
  }
  if (!flagged.empty()) canonical_force->bin();
  const double force_bound = bound / scale_max;
  double noise = 0.0;
  bool range = true;
  changes.clear();
  for (int i : flagged) {
    double clean[3];
    canonical_force->compute(i, clean);
    const double s = type_scale[type[i]];
    for (int d = 0; d < 3; d++) {
      const double difference = std::fabs(clean[d] - f[i][d]);
      if (!(difference <= noise)) noise = difference;    // NaN stays
      const double kq = round_odd(clean[d] * s);
      if (!(std::fabs(kq) < KICK_LIMIT)) {
        range = false;
        continue;
      }
      const double kv = kq * qv;
      if (kv == k[i][d] && std::signbit(kv) == std::signbit(k[i][d])) continue;
      changes.push_back({i, d, k[i][d], kv});
      if (applied) {
        v[i][d] -= k[i][d];
        v[i][d] += kv;
      }
      k[i][d] = kv;
    }
  }
  const bool impure = !range || !(noise <= force_bound);
  if (!flagged.empty()) {
    if (!(noise <= local_noise)) local_noise = noise;
    local_bound = std::min(local_bound, force_bound);
  }
  local_atoms += static_cast<double>(flagged.size());
  local_steps++;
  const int verdict = reduce_recomputed(impure ? IMPURE : 0, changes, applied);
  local_seconds += MPI_Wtime() - started;
  return verdict & IMPURE;
}

int FixReversibleNVE::reduce_recomputed(int mine, const std::vector<Change> &, bool)
{
  int verdict = mine;
  if (comm->nprocs > 1) MPI_Allreduce(&mine, &verdict, 1, MPI_INT, MPI_BOR, world);
  return verdict;
}

int FixReversibleNVE::pack_forward_comm(int n, int *list, double *buf, int /*pbc_flag*/,
                                        int * /*pbc*/)
{
  return canonical_force->pack_topology(n, list, buf);
}

void FixReversibleNVE::unpack_forward_comm(int n, int first, double *buf)
{
  canonical_force->unpack_topology(n, first, buf);
}

/* The step's one collective: the verdict bits of every rank, or'ed (a
   maximum of the masks would drop one rank's AMBIGUOUS beside another's
   NOT_CANONICAL). */

int FixReversibleNVE::reduce_verdict(int local)
{
  int verdict = local;
  if (comm->nprocs > 1) MPI_Allreduce(&local, &verdict, 1, MPI_INT, MPI_BOR, world);
  return verdict;
}

void FixReversibleNVE::halt(int why)
{
  flag = why;
  mode = HALTED;
  timer->force_timeout();
  forced_timeout = 1;
}

/* Whether this rank's atoms sit one to a fine sort bin, in bin order,
   as Atom::sort with those bins left them: then their order is a function
   of the positions.  The Python path's test, in the same arithmetic. */

bool FixReversibleNVE::sorted_canonically()
{
  const double *lo = domain->sublo;
  const double *hi = domain->subhi;
  long nbins[3];
  double per[3];
  for (int d = 0; d < 3; d++) {
    nbins[d] = std::max(static_cast<long>((hi[d] - lo[d]) * (1.0 / sort_bin)), 1L);
    per[d] = static_cast<double>(nbins[d]) / (hi[d] - lo[d]);
  }
  double **x = atom->x;
  long previous = -1;
  for (int i = 0; i < atom->nlocal; i++) {
    long index[3];
    for (int d = 0; d < 3; d++) {
      long j = static_cast<long>((x[i][d] - lo[d]) * per[d]);
      index[d] = std::min(std::max(j, 0L), nbins[d] - 1);
    }
    const long flat = (index[2] * nbins[1] + index[1]) * nbins[0] + index[0];
    if (i > 0 && !(flat > previous)) return false;
    previous = flat;
  }
  return true;
}

/* How far the run's forces at the taken-back step were from the clean
   ones, for the atoms this rank held both times; reduced over the ranks
   (every rank is in this setup). */

void FixReversibleNVE::compare_with_noisy()
{
  double **f = atom->f;
  const tagint *tag = atom->tag;
  double noise = 0.0;
  for (int i = 0; i < atom->nlocal; i++) {
    auto at = std::lower_bound(noisy_tag.begin(), noisy_tag.end(), tag[i]);
    if (at == noisy_tag.end() || *at != tag[i]) continue;
    const size_t j = at - noisy_tag.begin();
    for (int d = 0; d < 3; d++) noise = std::max(noise, std::fabs(f[i][d] - noisy_f[3 * j + d]));
  }
  double local[2] = {noise, -(noisy_bound / scale_max)};
  double all[2] = {local[0], local[1]};
  if (comm->nprocs > 1) MPI_Allreduce(local, all, 2, MPI_DOUBLE, MPI_MAX, world);
  observed = 1;
  observed_noise = all[0];
  observed_bound = -all[1];
}

void FixReversibleNVE::post_run()
{
  // A halt that ended this run must not end the next one before it starts.
  if (forced_timeout) timer->reset_timeout();
  forced_timeout = 0;
  // Between runs the pending kick is in the array the driver knows.
  if (parity) {
    double **from = atom->darray[next_index];
    double **to = atom->darray[kick_index];
    for (int i = 0; i < atom->nlocal; i++)
      for (int d = 0; d < 3; d++) to[i][d] = from[i][d];
    parity = 0;
  }
  // Maxima over the ranks (a bound as its negative, for the least), then
  // the recomputed atoms' sum.
  double mine[4] = {run_force, local_noise, -local_bound, local_seconds};
  double all[4] = {mine[0], mine[1], mine[2], mine[3]};
  double atoms = local_atoms;
  if (comm->nprocs > 1) {
    MPI_Allreduce(mine, all, 4, MPI_DOUBLE, MPI_MAX, world);
    MPI_Allreduce(&local_atoms, &atoms, 1, MPI_DOUBLE, MPI_SUM, world);
  }
  run_force_all = all[0];
  local_atoms_all = atoms;
  local_seconds_all = all[3];
  if (local_steps > 0) {
    observed = 1;
    observed_noise = all[1];
    observed_bound = -all[2];
  }
}

/* 0: the verdict that halted the latest run (0 if none); 1: the largest
   force component of that run; 2: 1 if a clean recomputation was compared
   with the run's forces, then 3: the largest difference and 4: the
   guard's bound for it (both over every rank); 5: the mode.  6 to 11 are
   the thermostat's (fix reversible/nvt); 12: the steps of the latest run
   whose flagged kicks were recomputed locally, 13: their atoms (over every
   rank), 14: why kicks are not recomputed locally (0: they are;
   CanonicalForce::Reason), 15: the wall time of those recomputations,
   seconds (the largest over the ranks). */

double FixReversibleNVE::compute_vector(int n)
{
  switch (n) {
    case 0: return flag;
    case 1: return run_force_all;
    case 2: return observed;
    case 3: return observed_noise;
    case 4: return observed_bound;
    case 5: return mode;
    case 12: return local_steps;
    case 13: return local_atoms_all;
    case 14: return local_reason;
    case 15: return local_seconds_all;
    default: return 0.0;
  }
}
