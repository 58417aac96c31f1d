/* Exact, reversible velocity Verlet as a LAMMPS fix (a plugin of
   ase-reversible, built on first use by ase_reversible.lammps.plugin).

   fix ID group reversible/nve kick NAME velocity_quantum Q
       force_noise F extent_factor E sort_bin B mode M scale S1 ... Sntypes

   The step is the one ase_reversible.lammps.integrator runs through
   fix move, fix external and fix halt, bit for bit: the same formula,
   rounding, guard and verdicts, with the per-step work in one loop and
   one collective.  The Python driver owns everything between steps (the
   grid, the take-back, the clean recomputation, refusals); this fix only
   steps and reports.  Its arguments are set by that driver, not by hand. */

#ifndef LMP_FIX_REVERSIBLE_NVE_H
#define LMP_FIX_REVERSIBLE_NVE_H

#include "fix.h"

#include <vector>

namespace LAMMPS_NS {

class FixReversibleNVE : public Fix {
 public:
  FixReversibleNVE(class LAMMPS *, int, char **);
  int setmask() override;
  void init() override;
  void setup_pre_neighbor() override;
  void setup(int) override;
  void initial_integrate(int) override;
  void post_force(int) override;
  void post_run() override;
  int modify_param(int, char **) override;
  double compute_vector(int) override;

  // The verdicts, reduced by maximum over the ranks: the values of the
  // Python path's flags (integrator.py), which reads either path's.
  enum { AMBIGUOUS = 1, NOT_CANONICAL = 2, OUT_OF_RANGE = 4 };
  enum Mode { START, REDO, STEP, HALTED };

 protected:
  // The exact velocities the kick adds to (v itself here; a thermostat
  // keeps its own) and what follows a kick that was taken.
  virtual double **exact_velocity();
  virtual void after_kick() {}
  // The step's one collective, over this rank's verdict bits (a subclass
  // may carry its own sums in it); returns the verdict of every rank.
  virtual int reduce_verdict(int);

  int mode, flag, forced_timeout;
  double qv, force_noise, extent_factor, sort_bin;
  bool canonical;                    // the latest setup left a canonical order
  std::vector<double> type_scale;    // index by type, [0] unused
  double scale_min, scale_max;
  bool uniform;
  int kick_index;                    // atom->darray index of the pending kick
  double run_force, run_force_all;   // largest |F| of this segment
  int observed;                      // a clean recomputation was compared
  double observed_noise, observed_bound;
  // The run's forces at a flagged step, by atom ID, for the comparison.
  std::vector<tagint> noisy_tag;
  std::vector<double> noisy_f;
  double noisy_bound;

  double **pending();
  void halt(int);
  bool sorted_canonically();
  void compare_with_noisy();
  void set_mode(const char *);
};

}    // namespace LAMMPS_NS

#endif
