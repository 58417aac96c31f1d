/* Exact, reversible velocity Verlet as a LAMMPS fix (a plugin of
   ase-reversible, built on first use by ase_reversible.lammps.plugin).

   fix ID group reversible/nve kick NAME next NAME2 velocity_quantum Q
       force_noise F extent_factor E sort_bin B mode M scale S1 ... Sntypes

   The step is the one ase_reversible.lammps.integrator runs through
   fix move, fix external and fix halt, bit for bit: the same formula,
   rounding, guard and verdicts, with the per-step work in one loop and
   one collective.  A kick the guard flags is recomputed on the rank that
   owns its atom, from a force summed in an order that does not depend on
   the decomposition (canonical_force.h), so a run takes the same steps on
   any number of ranks; where the styles have no such form, the step halts
   and the Python driver recomputes every force by a global setup, as it
   owns everything else between steps (the grid, the take-back,
   refusals).  Its arguments are set by that driver, not by hand. */

#ifndef LMP_FIX_REVERSIBLE_NVE_H
#define LMP_FIX_REVERSIBLE_NVE_H

#include "fix.h"
#include "canonical_force.h"

#include <vector>

namespace LAMMPS_NS {

class FixReversibleNVE : public Fix {
 public:
  FixReversibleNVE(class LAMMPS *, int, char **);
  ~FixReversibleNVE() override;
  int setmask() override;
  void init() override;
  void setup_pre_neighbor() override;
  void setup(int) override;
  void initial_integrate(int) override;
  void post_force(int) override;
  void post_run() override;
  int modify_param(int, char **) override;
  double compute_vector(int) override;
  int pack_forward_comm(int, int *, double *, int, int *) override;
  void unpack_forward_comm(int, int, double *) override;

  // The verdicts, or'ed over the ranks: the values of the Python path's
  // flags (python_step.py), which the driver reads from either path.
  // IMPURE: a recomputed force differed from the run's by more than the
  // guard's bound.  (8 is the thermostat's.)
  enum { AMBIGUOUS = 1, NOT_CANONICAL = 2, OUT_OF_RANGE = 4, IMPURE = 16 };
  enum Mode { START, REDO, STEP, HALTED };

 protected:
  // The exact velocities the kick adds to (v itself here; a thermostat
  // keeps its own) and what follows a kick that was taken.
  virtual double **exact_velocity();
  virtual void after_kick() {}
  // The step's one collective, over this rank's verdict bits (a subclass
  // may carry its own sums in it); returns the verdict of every rank.
  // The step's kicks are in next_kicks() by then.
  virtual int reduce_verdict(int);
  // A kick component replaced by its canonical recomputation (velocity
  // units), for a subclass's sums.
  struct Change {
    int i, d;
    double before, after;
  };
  // The collective of a step with flagged atoms anywhere, after their
  // kicks were recomputed: every rank calls it.  Returns every rank's bits.
  virtual int reduce_recomputed(int, const std::vector<Change> &, bool applied);

  int mode, flag, forced_timeout;
  double qv, force_noise, extent_factor, sort_bin;
  bool canonical;                    // the latest setup left a canonical order
  std::vector<double> type_scale;    // index by type, [0] unused
  double scale_min, scale_max;
  bool uniform;
  int kick_index;                    // atom->darray index of the pending kick
  int next_index;                    // and of the array the next kicks go to
  int parity;                        // 1: the pending kick is in next_index's
  CanonicalForce *canonical_force;
  int local_reason;                  // CanonicalForce::LOCAL: recompute locally
  std::vector<int> candidates;       // atoms the guard may flag this step
  double last_force;                 // the largest |F| of the previous step
  std::vector<Change> changes;
  int local_steps;                   // steps with recomputed kicks (this run)
  double local_atoms;                // their atoms, this rank's
  double local_atoms_all;            // and every rank's, after the run
  double local_seconds, local_seconds_all;    // their wall time
  double local_noise, local_bound;   // largest |F_run - F_canonical|, its bound
  double run_force, run_force_all;   // largest |F| of this segment
  int observed;                      // a clean recomputation was compared
  double observed_noise, observed_bound;
  // The run's forces at a flagged step, by atom ID, for the comparison.
  std::vector<tagint> noisy_tag;
  std::vector<double> noisy_f;
  double noisy_bound;

  double **pending();
  double **next_kicks();
  void flip();
  bool recompute_flagged(double bound, double guess, bool applied);
  void halt(int);
  bool sorted_canonically();
  void compare_with_noisy();
  void set_mode(const char *);
};

}    // namespace LAMMPS_NS

#endif
