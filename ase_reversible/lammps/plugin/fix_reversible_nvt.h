/* Exact, reversible Nose dynamics (NVT) as a LAMMPS fix (a plugin of
   ase-reversible, built on first use by ase_reversible.lammps.plugin).

   fix ID all reversible/nvt kick NAME virtual NAME velocity_quantum Q
       force_noise F extent_factor E mode M scale S1 ... Sntypes
       thermostat S PI CLOCK quanta QS QPI QCLOCK kT KT dof G mass Q

   Nose's extended Hamiltonian in virtual time, split into exact shears
   as ase_reversible.md.nose splits it: a step is B/2 C/2 A C/2 B/2 with
   B the kick of the virtual velocities v' = s v, C the drift of s
   (s += h pi / Q) and A the drift of the positions (x += h v' / s^2),
   the kick of pi (pi += h (mvv2e sum m v'^2 / s^3 - g kT / s)) and the
   real-time clock (t += h / s).  Every increment is rounded odd to its
   quantum, so a step of -h undoes a step of h bit for bit.  LAMMPS's v
   shows v' / s.  Set up by ase_reversible.lammps.nose, not by hand. */

#ifndef LMP_FIX_REVERSIBLE_NVT_H
#define LMP_FIX_REVERSIBLE_NVT_H

#include "fix_reversible_nve.h"

#include <string>
#include <vector>

namespace LAMMPS_NS {

class FixReversibleNVT : public FixReversibleNVE {
 public:
  FixReversibleNVT(class LAMMPS *, int, char **);
  void initial_integrate(int) override;
  int modify_param(int, char **) override;
  double compute_vector(int) override;
  void write_restart(FILE *) override;
  void restart(char *) override;

  // s would have reached zero or below: the step was not taken.
  enum { S_NOT_POSITIVE = 8 };

 protected:
  double **exact_velocity() override;
  void after_kick() override;
  int reduce_verdict(int) override;
  int reduce_recomputed(int, const std::vector<Change> &, bool) override;
  int reduce_squares(int, const std::vector<unsigned __int128> &,
                     const std::vector<unsigned __int128> &);

  std::string virtual_name;
  int virtual_index;
  double qx;                       // the position quantum
  double s, pi, clock;             // the thermostat's exact state
  double qs, qpi, qclock;          // and its quanta
  double kT, dof, mass_q;
  double k2;                       // sum m v'^2 after the next B/2, exact
  std::vector<unsigned __int128> totals;    // its integer sums, per type
  // What initial_integrate changed, for fix_modify ID undo.
  int half_done;
  double s_before, pi_before, clock_before, k2_before, drift_factor;
  int drift_range;                 // this rank's drift left the grid's range

  void show_velocities();
  void undo();
};

}    // namespace LAMMPS_NS

#endif
