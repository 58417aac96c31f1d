/* Exact, reversible Nose dynamics as a LAMMPS fix: see the header.

   Built with -ffp-contract=off and without -ffast-math: every product and
   quotient below is rounded on its own, so a step of -h computes every
   increment as the exact negative of the step of h it undoes. */

#include "fix_reversible_nvt.h"

#include "atom.h"
#include "comm.h"
#include "error.h"
#include "force.h"
#include "timer.h"
#include "update.h"

#include <cmath>
#include <cstring>
#include <vector>

using namespace LAMMPS_NS;

namespace {

constexpr double MAGIC = 6755399441055744.0;    // 1.5 * 2^52
// Increments of the drift and of the thermostat's variables stay below
// 2^50 quanta: rounded exactly by MAGIC, and summed exactly onto values
// whose counts stay below 2^53.
constexpr double INCREMENT_LIMIT = 1125899906842624.0;
// Virtual velocity counts below 2^50: recovered exactly from (v, s), and
// their squares summed in 128 bits without overflow for 2^26 per rank.
constexpr double COUNT_LIMIT = 1125899906842624.0;

inline double round_odd(double y)
{
  return std::copysign((y + MAGIC) - MAGIC, y);
}

// The keywords of this class and how many values each takes: the base
// class's constructor sees the arguments without them.
int own_values(const char *word)
{
  static const char *names[] = {"virtual", "thermostat", "quanta", "kT", "dof", "mass",
                                "position_quantum"};
  static const int values[] = {1, 3, 3, 1, 1, 1, 1};
  for (int i = 0; i < 7; i++)
    if (strcmp(word, names[i]) == 0) return values[i];
  return -1;
}

std::vector<char *> &base_arguments(int narg, char **arg)
{
  static std::vector<char *> kept;
  kept.clear();
  for (int i = 0; i < narg; i++) {
    const int n = (i >= 3) ? own_values(arg[i]) : -1;
    if (n >= 0) {
      i += n;
      continue;
    }
    kept.push_back(arg[i]);
  }
  return kept;
}

}    // namespace

FixReversibleNVT::FixReversibleNVT(LAMMPS *lmp, int narg, char **arg) :
    FixReversibleNVE(lmp, static_cast<int>(base_arguments(narg, arg).size()),
                     base_arguments(narg, arg).data()),
    virtual_index(-1), qx(0.0), s(1.0), pi(0.0), clock(0.0), qs(0.0), qpi(0.0), qclock(0.0), kT(0.0),
    dof(0.0), mass_q(0.0), k2(0.0), half_done(0), s_before(1.0), pi_before(0.0),
    clock_before(0.0), k2_before(0.0), drift_factor(0.0), drift_range(0)
{
  restart_global = 1;
  size_vector = 16;
  for (int i = 3; i < narg; i++) {
    const int n = own_values(arg[i]);
    if (n < 0) continue;
    if (i + n >= narg) error->all(FLERR, "fix {} keyword {} needs {} values", style, arg[i], n);
    const std::string key = arg[i];
    auto value = [&](int j) { return utils::numeric(FLERR, arg[i + j], false, lmp); };
    if (key == "virtual") virtual_name = arg[i + 1];
    else if (key == "thermostat") { s = value(1); pi = value(2); clock = value(3); }
    else if (key == "quanta") { qs = value(1); qpi = value(2); qclock = value(3); }
    else if (key == "kT") kT = value(1);
    else if (key == "dof") dof = value(1);
    else if (key == "mass") mass_q = value(1);
    else if (key == "position_quantum") qx = value(1);
    i += n;
  }
  int is_double, cols;
  virtual_index = atom->find_custom(virtual_name.c_str(), is_double, cols);
  if (virtual_index < 0 || is_double != 1 || cols != 3)
    error->all(FLERR, "fix {} needs virtual NAME: a d2_ property/atom of 3 columns", style);
  if (!(s > 0.0)) error->all(FLERR, "fix {}: the thermostat's s must be positive", style);
}

double **FixReversibleNVT::exact_velocity()
{
  return atom->darray[virtual_index];
}

/* LAMMPS's v shows the real velocities v' / s. */

void FixReversibleNVT::show_velocities()
{
  double **v = atom->v;
  double **w = exact_velocity();
  for (int i = 0; i < atom->nlocal; i++)
    for (int d = 0; d < 3; d++) v[i][d] = w[i][d] / s;
}

void FixReversibleNVT::after_kick()
{
  show_velocities();
}

/* B/2 (the pending kick) C/2 A C/2: the thermostat's variables first, from
   the exact sum of the previous post_force, so that a step which would
   take s to zero or below changes nothing. */

void FixReversibleNVT::initial_integrate(int /*vflag*/)
{
  half_done = 0;
  if (mode == HALTED) return;
  const double h = update->dt;
  const double s_step = (0.5 * h) / (mass_q * qs);
  double ys = s_step * pi;
  bool range = std::fabs(ys) < INCREMENT_LIMIT;
  const double s1 = s + round_odd(ys) * qs;
  const double s1_cubed = (s1 * s1) * s1;
  const double f_pi = (force->mvv2e * k2) / s1_cubed - (dof * kT) / s1;
  const double ypi = (h / qpi) * f_pi;
  range = range && std::fabs(ypi) < INCREMENT_LIMIT;
  const double pi1 = pi + round_odd(ypi) * qpi;
  const double yt = (h / qclock) / s1;
  range = range && std::fabs(yt) < INCREMENT_LIMIT;
  const double clock1 = clock + round_odd(yt) * qclock;
  ys = s_step * pi1;
  range = range && std::fabs(ys) < INCREMENT_LIMIT;
  const double s2 = s1 + round_odd(ys) * qs;
  if (!range || !(s1 > 0.0) || !(s2 > 0.0)) {
    // The same on every rank: the thermostat's variables are global.
    halt(range ? S_NOT_POSITIVE : OUT_OF_RANGE);
    return;
  }
  s_before = s;
  pi_before = pi;
  clock_before = clock;
  k2_before = k2;
  s = s2;
  pi = pi1;
  clock = clock1;

  // B/2, then the drift with s after C/2: x += q_x rint(h v' / (s^2 q_x)).
  drift_factor = (h / (s1 * s1)) / qx;
  double **x = atom->x;
  double **w = exact_velocity();
  double **k = pending();
  const int nlocal = atom->nlocal;
  for (int i = 0; i < nlocal; i++) {
    for (int d = 0; d < 3; d++) {
      w[i][d] += k[i][d];
      const double y = w[i][d] * drift_factor;
      // Beyond the range an atom stays put (undo skips it the same way)
      // and the step's verdict halts the run.
      if (std::fabs(y) < INCREMENT_LIMIT) x[i][d] += round_odd(y) * qx;
      else drift_range = 1;
    }
  }
  half_done = 1;
}

/* fix_modify ID undo: the inverse of initial_integrate, for a step that
   stopped before its kick (the driver then resets the step number). */

void FixReversibleNVT::undo()
{
  if (!half_done) return;
  double **x = atom->x;
  double **w = exact_velocity();
  double **k = pending();
  for (int i = 0; i < atom->nlocal; i++) {
    for (int d = 0; d < 3; d++) {
      const double y = w[i][d] * drift_factor;
      if (std::fabs(y) < INCREMENT_LIMIT) x[i][d] -= round_odd(y) * qx;
      w[i][d] -= k[i][d];
    }
  }
  s = s_before;
  pi = pi_before;
  clock = clock_before;
  k2 = k2_before;
  half_done = 0;
  show_velocities();
}

int FixReversibleNVT::modify_param(int narg, char **arg)
{
  if (strcmp(arg[0], "undo") == 0) {
    undo();
    return 1;
  }
  if (strcmp(arg[0], "takeback") == 0) {
    // The kick of a flagged step, taken back before its clean redo.
    double **w = exact_velocity();
    double **k = pending();
    for (int i = 0; i < atom->nlocal; i++)
      for (int d = 0; d < 3; d++) w[i][d] -= k[i][d];
    show_velocities();
    return 1;
  }
  return FixReversibleNVE::modify_param(narg, arg);
}

/* The step's one collective, with MPI_SUM over 64-bit integers: the
   verdict bits as counts of ranks, then, per atom type, the sum of the
   squared counts of v' after the next step's B/2 (v' + k with this step's
   kick k, which a step, unlike a start, has also added to v' already), in
   32-bit limbs.  Integer sums do not depend on which rank holds which
   atom or in what order, so every rank gets the same bits of sum m v'^2
   on any decomposition. */

int FixReversibleNVT::reduce_verdict(int local)
{
  const int ntypes = atom->ntypes;
  const int nlocal = atom->nlocal;
  const int *type = atom->type;
  double **w = exact_velocity();
  double **k = next_kicks();
  const double inv_qv = 1.0 / qv;
  std::vector<unsigned __int128> squares(ntypes + 1, 0);
  if (drift_range) local |= OUT_OF_RANGE;
  drift_range = 0;
  if (!(local & OUT_OF_RANGE)) {
    for (int i = 0; i < nlocal && !(local & OUT_OF_RANGE); i++) {
      for (int d = 0; d < 3; d++) {
        const double c = (w[i][d] + k[i][d]) * inv_qv;
        if (!(std::fabs(c) < COUNT_LIMIT)) {
          local |= OUT_OF_RANGE;
          break;
        }
        const long long n = static_cast<long long>(c);
        squares[type[i]] += static_cast<unsigned __int128>(static_cast<__int128>(n) * n);
      }
    }
  }
  std::vector<unsigned __int128> none;
  return reduce_squares(local, squares, none);
}

/* The sums again where flagged kicks were recomputed: each changed
   component's square before (as reduce_verdict counted it) taken off and
   its square after added, per type, summed over the ranks in the same
   integer arithmetic (modulo 2^128: the totals are never negative). */

int FixReversibleNVT::reduce_recomputed(int local, const std::vector<Change> &changes,
                                        bool applied)
{
  const int ntypes = atom->ntypes;
  const int *type = atom->type;
  double **w = exact_velocity();
  const double inv_qv = 1.0 / qv;
  std::vector<unsigned __int128> added(ntypes + 1, 0), removed(ntypes + 1, 0);
  for (const Change &c : changes) {
    const double now = w[c.i][c.d];
    const double before = applied ? (now - c.after) + c.before : now;
    const double count_after = (now + c.after) * inv_qv;
    const double count_before = (before + c.before) * inv_qv;
    if (!(std::fabs(count_after) < COUNT_LIMIT)) {
      local |= IMPURE;    // the step is taken: it cannot halt as unstepped
      continue;
    }
    const long long a = static_cast<long long>(count_after);
    const long long b = static_cast<long long>(count_before);
    added[type[c.i]] += static_cast<unsigned __int128>(static_cast<__int128>(a) * a);
    removed[type[c.i]] += static_cast<unsigned __int128>(static_cast<__int128>(b) * b);
  }
  return reduce_squares(local, added, removed);
}

/* Sum the verdict bits and, per type, added - removed squares into the
   totals (reset first where nothing is removed: a step's own sums), then
   k2 from the totals: one rounding per type, the types in a fixed order. */

int FixReversibleNVT::reduce_squares(int local, const std::vector<unsigned __int128> &added,
                                     const std::vector<unsigned __int128> &removed)
{
  const int ntypes = atom->ntypes;
  const bool fresh = removed.empty();
  const int nbits = 5, nlimbs = 4, ngroups = fresh ? 1 : 2;
  std::vector<long long> mine(nbits + ngroups * nlimbs * ntypes, 0), all(mine.size(), 0);
  for (int b = 0; b < nbits; b++) mine[b] = (local >> b) & 1;
  for (int g = 0; g < ngroups; g++) {
    const std::vector<unsigned __int128> &sums = g ? removed : added;
    for (int t = 1; t <= ntypes; t++)
      for (int j = 0; j < nlimbs; j++)
        mine[nbits + nlimbs * (g * ntypes + t - 1) + j] =
            static_cast<long long>((sums[t] >> (32 * j)) & 0xffffffffu);
  }
  if (comm->nprocs > 1)
    MPI_Allreduce(mine.data(), all.data(), static_cast<int>(mine.size()), MPI_LONG_LONG, MPI_SUM,
                  world);
  else
    all = mine;
  int verdict = 0;
  for (int b = 0; b < nbits; b++)
    if (all[b] > 0) verdict |= 1 << b;
  if (verdict & OUT_OF_RANGE) return verdict;
  if (fresh) totals.assign(ntypes + 1, 0);
  for (int g = 0; g < ngroups; g++) {
    for (int t = 1; t <= ntypes; t++) {
      unsigned __int128 sum = 0;
      for (int j = 0; j < nlimbs; j++)
        sum += static_cast<unsigned __int128>(all[nbits + nlimbs * (g * ntypes + t - 1) + j])
            << (32 * j);
      if (g == 0) totals[t] += sum;
      else totals[t] -= sum;
    }
  }
  double sum = 0.0;
  const double *mass = atom->mass;
  for (int t = 1; t <= ntypes; t++)
    sum += (mass[t] * (qv * qv)) * static_cast<double>(totals[t]);
  k2 = sum;
  return verdict;
}

void FixReversibleNVT::write_restart(FILE *fp)
{
  double list[6] = {s, pi, clock, qs, qpi, qclock};
  if (comm->me == 0) {
    int size = sizeof(list);
    fwrite(&size, sizeof(int), 1, fp);
    fwrite(list, sizeof(double), 6, fp);
  }
}

/* A restart file's state wins over the arguments: the driver reads it
   back through compute_vector. */

void FixReversibleNVT::restart(char *buf)
{
  auto list = reinterpret_cast<double *>(buf);
  s = list[0];
  pi = list[1];
  clock = list[2];
  qs = list[3];
  qpi = list[4];
  qclock = list[5];
}

/* 0 to 5 as fix reversible/nve; 6: s, 7: pi, 8: the clock (LAMMPS time
   units); 9 to 11: their quanta (a restart file's, if it set the state). */

double FixReversibleNVT::compute_vector(int n)
{
  switch (n) {
    case 6: return s;
    case 7: return pi;
    case 8: return clock;
    case 9: return qs;
    case 10: return qpi;
    case 11: return qclock;
    default: return FixReversibleNVE::compute_vector(n);
  }
}
