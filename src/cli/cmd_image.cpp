// qdo image: the RGB sensor image of one scene with the skipping rules of Camera
// (include/qdo/physics/camera.hpp) and a JSON report of what was skipped and the bound; the work is
// the library's (plan_image, run_image: include/qdo/asbuilt/simulate.hpp).
#include <cstdio>

#include "cli.hpp"
#include "qdo/asbuilt/simulate.hpp"
#include "qdo/runtime/runtime.hpp"

namespace qdo::cli {

static int cmd_image(const Args& a) {
  const ImagePlan q = plan_image(a);  // every option checked, the scene and PSF read
  const std::string dir = out_dir(a);
  Runtime rt(a.get("device"));
  std::fputs(run_image(rt, q, dir).c_str(), stdout);
  return 0;
}

// qdo image: its entry in the command table (help order 140).
const RegisterCommand registered_image(140, [] {
  using namespace opts;
  return CommandSpec{"image", "the RGB sensor image of one scene with the skipping rules of Camera and a skip report", "", "",
                   {preset(), config(), design_spec(), psf_file(), levels_post(), placement(), scene(), key(), resample_bands(), precision(),
                    device(), opt("tolerance", "error bound of the skipped work, in units of full scale, in [0, 1]", "3e-7"),
                    flag("exact", "skip nothing"), opt("tiles", "tiled convolution: off, on or auto", "off"),
                    opt("tile-px", "tile size in sensor pixels, an integer in [8, 4096]", "64"), out_dir_opt()},
                   cmd_image};
});

}  // namespace qdo::cli
