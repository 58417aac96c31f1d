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
    scale_max(0.0), uniform(true), kick_index(-1), run_force(0.0),
    run_force_all(0.0), observed(0), observed_noise(0.0),
    observed_bound(0.0), noisy_bound(0.0)
{
  if (igroup != 0)
    error->all(FLERR, "fix {} acts on group all: exact runs move every atom", style);
  time_integrate = 1;
  vector_flag = 1;
  size_vector = 6;
  global_freq = 1;
  extvector = 0;

  const int ntypes = atom->ntypes;
  type_scale.assign(ntypes + 1, 0.0);
  std::string kick;
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
  scale_min = scale_max = std::fabs(type_scale[1]);
  for (int t = 1; t <= ntypes; t++) {
    scale_min = std::min(scale_min, std::fabs(type_scale[t]));
    scale_max = std::max(scale_max, std::fabs(type_scale[t]));
    if (type_scale[t] != type_scale[1]) uniform = false;
  }
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

double **FixReversibleNVE::pending()
{
  // Fetched at each use: the array moves when atoms are added to it.
  return atom->darray[kick_index];
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
   guarded: the verdicts and what is applied on each are the Python
   path's (ReversibleLammps._callback).  The kicks are computed twice, to
   judge them and then to apply them once judged on every rank:
   recomputing costs less than storing and reading them back. */

void FixReversibleNVE::post_force(int /*vflag*/)
{
  if (mode == HALTED) return;
  const int nlocal = atom->nlocal;
  double **f = atom->f;
  const int *type = atom->type;
  double r_max = 0.0, deviation = 0.0, f_abs = 0.0;
  bool out_of_range = false;
  for (int i = 0; i < nlocal; i++) {
    const double s = type_scale[type[i]];
    for (int d = 0; d < 3; d++) {
      const double y = f[i][d] * s;
      const double k = round_odd(y);
      const double a = std::fabs(k);
      if (!(a < KICK_LIMIT)) out_of_range = true;    // also NaN
      if (a > r_max) r_max = a;
      const double e = std::fabs(y - k);
      if (e > deviation) deviation = e;
      if (!uniform) {
        const double fa = std::fabs(f[i][d]);
        if (fa > f_abs) f_abs = fa;
      }
    }
  }
  // With one mass the largest kick bounds the largest force; with several
  // it would overstate it by the mass ratio.
  const double f_max = uniform ? (r_max + 0.5) / scale_min : f_abs;
  if (f_max > run_force) run_force = f_max;
  const double bound = force_noise * extent_factor * std::max(1.0, f_max) * scale_max;
  int local = 0;
  if (out_of_range) local |= OUT_OF_RANGE;
  else if (deviation > 0.5 - bound) local |= AMBIGUOUS;
  const bool setup = (mode == START || mode == REDO);
  if (setup && !canonical) local |= NOT_CANONICAL;
  const int verdict = reduce_verdict(local);

  if (verdict & OUT_OF_RANGE) {
    halt(OUT_OF_RANGE);
    return;
  }
  double **k = pending();
  double **v = exact_velocity();
  if (setup) {
    if ((verdict & AMBIGUOUS) && (verdict & NOT_CANONICAL)) {
      // The clean forces may depend on history after all: take nothing,
      // and let the driver undo the drift and retry with finer bins.
      for (int i = 0; i < nlocal; i++) k[i][0] = k[i][1] = k[i][2] = 0.0;
      halt(NOT_CANONICAL);
      return;
    }
    const bool redo = (mode == REDO);
    if (redo) compare_with_noisy();
    for (int i = 0; i < nlocal; i++) {
      const double s = type_scale[type[i]];
      for (int d = 0; d < 3; d++) {
        const double kv = round_odd(f[i][d] * s) * qv;
        if (redo) v[i][d] += kv;
        k[i][d] = kv;
      }
    }
    mode = STEP;
    after_kick();
    return;
  }
  for (int i = 0; i < nlocal; i++) {
    const double s = type_scale[type[i]];
    for (int d = 0; d < 3; d++) {
      const double kv = round_odd(f[i][d] * s) * qv;
      v[i][d] += kv;
      k[i][d] = kv;
    }
  }
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

/* The step's one collective: the verdict's maximum over the ranks. */

int FixReversibleNVE::reduce_verdict(int local)
{
  int verdict = local;
  if (comm->nprocs > 1) MPI_Allreduce(&local, &verdict, 1, MPI_INT, MPI_MAX, world);
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
  run_force_all = run_force;
  if (comm->nprocs > 1) MPI_Allreduce(&run_force, &run_force_all, 1, MPI_DOUBLE, MPI_MAX, world);
}

/* 0: the verdict that halted the latest run (0 if none); 1: the largest
   force component of that run; 2: 1 if a clean recomputation was compared
   with the run's forces, then 3: the largest difference and 4: the
   guard's bound for it (both over every rank); 5: the mode. */

double FixReversibleNVE::compute_vector(int n)
{
  switch (n) {
    case 0: return flag;
    case 1: return run_force_all;
    case 2: return observed;
    case 3: return observed_noise;
    case 4: return observed_bound;
    case 5: return mode;
    default: return 0.0;
  }
}
