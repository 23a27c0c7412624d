// qdo sweep-psf: PSF quality against the number of levels for one design (sweep.hpp; the options
// read by sweep_text.hpp); this file claims --out, opens the device and prints.
#include <chrono>
#include <cstdio>

#include "cli.hpp"
#include "qdo/evaluate/sweep_text.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_sweep_psf(const Args& a) {
  PsfSweepOptions o = psf_sweep_options_from_options(a);  // every option checked, the design read
  o.out = out_dir(a);
  Runtime rt(a.get("device"));
  const auto t0 = std::chrono::steady_clock::now();
  std::fputs(psf_sweep_table(sweep_psf(rt, o)).c_str(), stdout);
  std::printf("(means over %zu bands) %.1f s; wrote %s/ (sweep.csv sweep.json psf.h5 psf_*.png *_vs_variant.png)\n", o.cfg.bands,
              seconds_since(t0), o.out.c_str());
  return 0;
}

// qdo sweep-psf: its entry in the command table (help order 190).
const RegisterCommand registered_sweep_psf(190, [] {
  using namespace opts;
  return CommandSpec{"sweep-psf", "PSF quality against the number of levels for one design", "", "",
                   {opt("design", "a design .h5 file or a run folder"),
                    opt("levels", "level counts, comma-separated integers in [2, 65536]", "2,4,8,16,32"), placement(),
                    opt("adaptive-from", "also the adaptive levels of this qdo+a run folder"), preset(), config(), precision(), device(),
                    opt("designs-per-pass", "designs per device pass, an integer in [0, 1000] (0: automatic)", "0"), out_dir_opt()},
                   cmd_sweep_psf, true};
});

}  // namespace qdo::cli
