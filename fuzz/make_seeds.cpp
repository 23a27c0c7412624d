// qdo_fuzz_seeds: writes the seed inputs of every fuzz target into CORPUS_DIR/<target>/seed-*
// (valid files of each format, plus a few typical broken ones). Regenerate with
//   cmake --build build --target qdo_fuzz_seeds && build/qdo_fuzz_seeds fuzz/corpus
// Regression inputs (crash-*) are kept as they are, and so is fuzz/corpus/run_folder/
// real-qdo-design-n16: the config.json, checkpoint.h5 and log.csv of a real `qdo design` run
// (N = 16, 3 bands, qdo+a, L = 4, --max-steps 3), joined by fuzz::kFileSeparator.
#include <matio.h>
#include <png.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/design/design.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/embedded.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/runtime/kernel_cache.hpp"
#include "qdo/design/run.hpp"

#include "fuzz_util.hpp"

namespace fs = std::filesystem;
using namespace qdo;

namespace {

void text(const fs::path& p, const std::string& s) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << s;
  if (!out) throw Error("cannot write " + p.string());
}

struct MatCloser {
  void operator()(mat_t* m) const { Mat_Close(m); }
};
struct MatVarFreer {
  void operator()(matvar_t* v) const { Mat_VarFree(v); }
};

// One 3-D variable (MATLAB dims, column-major data) per file.
template <typename T>
void mat(const fs::path& p, mat_ft ver, const std::string& name, std::vector<std::size_t> dims, matio_classes cls,
         matio_types type, std::vector<T> data, matio_compression comp) {
  std::unique_ptr<mat_t, MatCloser> m(Mat_CreateVer(p.c_str(), nullptr, ver));
  if (!m) throw Error("cannot create " + p.string());
  std::unique_ptr<matvar_t, MatVarFreer> v(
      Mat_VarCreate(name.c_str(), cls, type, int(dims.size()), dims.data(), data.data(), MAT_F_DONT_COPY_DATA));
  if (!v || Mat_VarWrite(m.get(), v.get(), comp) != 0) throw Error("cannot write " + p.string());
}

void png(const fs::path& p, std::uint32_t w, std::uint32_t h, std::uint32_t format, const void* px) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = w;
  img.height = h;
  img.format = format;
  const int ok = png_image_write_to_file(&img, p.c_str(), 0, px, 0, nullptr);
  png_image_free(&img);
  if (!ok) throw Error("cannot write " + p.string());
}

std::vector<double> ramp(std::size_t n, double scale) {
  std::vector<double> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = scale * double(i % 17) / 16.0;
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]);
    return 2;
  }
  const fs::path root = argv[1];
  auto dir = [&](const std::string& t) {
    fs::create_directories(root / t);
    return root / t;
  };
  try {
    // ---- config (JSON)
    const fs::path c = dir("config");
    text(c / "seed-small.json", config_to_json_text(preset_config("small")));
    text(c / "seed-paper.json", config_to_json_text(preset_config("paper")));
    text(c / "seed-inf.json", R"({"preset": "small", "scene_distance_m": "inf", "propagator": "asm", "bands": 3})");
    text(c / "seed-custom.json",
         R"({"n": 64, "pitch_m": 2e-6, "bands": 301, "wavelength_start_nm": 400, "wavelength_step_nm": 1, "srf_interpolate": true, "camera": "x.csv"})");
    text(c / "seed-badtype.json", R"({"n": "64", "strict_sampling": 1})");
    text(c / "seed-unknown.json", R"({"pitch": 4e-6})");
    text(c / "seed-truncated.json", R"({"preset": "small", "n": 2)");
    text(c / "seed-nested.json", R"({"n": [[[[[[[[[[1]]]]]]]]]]})");
    // ---- camera raw (DNG through LibRaw)
    const fs::path cr = dir("capture_raw");
    for (const char* cfa : {"rggb", "bggr", "grbg", "gbrg"}) {
      Map2D m(24, 26);
      for (std::size_t i = 0; i < m.data.size(); ++i) m.data[i] = double(64 + (i * 37) % 4000);
      write_dng_mosaic((cr / (std::string("seed-") + cfa + ".dng")).string(), m, cfa, 64, 4095);
    }
    {
      Map2D odd(23, 25);
      for (std::size_t i = 0; i < odd.data.size(); ++i) odd.data[i] = double((i * 977) % 65536);
      write_dng_mosaic((cr / "seed-odd-16bit.dng").string(), odd, "rggb", 0, 65535);
      std::ifstream in(cr / "seed-rggb.dng", std::ios::binary);
      std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      text(cr / "seed-truncated.dng", bytes.substr(0, bytes.size() / 2));
    }
    // ---- design (HDF5)
    const fs::path d = dir("design_h5");
    Design des;
    des.height_m = Map2D(4, 4);
    des.height_m.data = ramp(16, 1e-6);
    des.pitch_m = 4e-6;
    write_design((d / "seed-plain.h5").string(), des);
    des.levels_m = {0, 0.5e-6, 1e-6};
    write_design((d / "seed-levels.h5").string(), des, {{"mode", "qdo+a"}});
    // ---- cube (HDF5)
    const fs::path ch = dir("cube_h5");
    RealStack cube(3, 4, 5);
    cube.data = ramp(60, 1.0);
    write_cube((ch / "seed-cube.h5").string(), cube, {450, 500, 550});
    write_cube((ch / "seed-cube-shifted-axis.h5").string(), cube, {455, 505, 555});
    write_cube((ch / "seed-cube-reversed-axis.h5").string(), cube, {550, 500, 450});
    write_cube((ch / "seed-cube-um-axis.h5").string(), cube, {0.45, 0.5, 0.55});
    RealStack hdr = cube;
    for (double& v : hdr.data) v = 40.0 * v - 0.2;  // HDR with slightly negative values
    write_cube((ch / "seed-cube-hdr.h5").string(), hdr, {450, 500, 550});
    h5_write((ch / "seed-rad.h5").string(), {H5Dataset{"/rad", {3, 4, 5}, ramp(60, 4095), {}, {}}});
    // ---- MATLAB
    const fs::path m = dir("mat");
    std::vector<std::uint16_t> u16(60);
    for (std::size_t i = 0; i < u16.size(); ++i) u16[i] = std::uint16_t(i * 1000);
    mat(m / "seed-v5-u16.mat", MAT_FT_MAT5, "cube", {4, 5, 3}, MAT_C_UINT16, MAT_T_UINT16, u16, MAT_COMPRESSION_NONE);
    mat(m / "seed-v5-zlib.mat", MAT_FT_MAT5, "ref", {4, 5, 3}, MAT_C_DOUBLE, MAT_T_DOUBLE, ramp(60, 3.0), MAT_COMPRESSION_ZLIB);
    mat(m / "seed-v73.mat", MAT_FT_MAT73, "rad", {4, 5, 3}, MAT_C_DOUBLE, MAT_T_DOUBLE, ramp(60, 4095), MAT_COMPRESSION_NONE);
    mat(m / "seed-v5-single.mat", MAT_FT_MAT5, "HSI", {3, 4, 5}, MAT_C_SINGLE, MAT_T_SINGLE,
        std::vector<float>(60, 0.25f), MAT_COMPRESSION_NONE);
    // ---- checkpoint
    const fs::path k = dir("checkpoint");
    DesignState s;
    s.w = ramp(16, 0.5);
    s.offsets = {0, 0.1, -0.2, 0.05};
    s.adam_w.m = ramp(16, 1e-3);
    s.adam_w.v = ramp(16, 1e-6);
    s.adam_w.t = 7;
    s.step = 7;
    save_checkpoint((k / "seed-checkpoint.h5").string(), s);
    // ---- PNG bands
    const fs::path p = dir("png");
    const std::vector<std::uint8_t> g8 = {0, 64, 128, 255, 1, 2, 3, 4, 5, 6, 7, 8};
    const std::vector<std::uint16_t> g16 = {0, 65535, 4096, 30000, 1, 2, 3, 4, 5, 6, 7, 8};
    png(p / "seed-gray8.png", 4, 3, PNG_FORMAT_GRAY, g8.data());
    png(p / "seed-gray16.png", 4, 3, PNG_FORMAT_LINEAR_Y, g16.data());
    std::vector<std::uint8_t> rgb(36, 100);
    png(p / "seed-rgb.png", 4, 3, PNG_FORMAT_RGB, rgb.data());
    // ---- CSV
    const fs::path v = dir("csv");
    text(v / "seed-flir.csv", embedded_file("srf_FLIR_GS3-U3-41S4C.csv"));
    text(v / "seed-small.csv", "# a comment\nwavelength_nm,R,G,B\n400,0.1,0.2,0.3\n500,0.5,0.6,0.1\n700,0.9,0.1,0.0\n");
    text(v / "seed-ragged.csv", "wavelength_nm,R,G,B\n400,1,2\n");
    text(v / "seed-names.csv", "name,400,410\nleaf,0.1,x\n");
    // ---- kernel cache entries
    const fs::path kc = dir("kernel_cache");
    std::string bin = "\x7f" "ELF";
    for (int i = 0; i < 200; ++i) bin += static_cast<char>((i * 37) & 0xff);  // a pretend program binary
    const auto entry = encode_kernel_cache_entry(reinterpret_cast<const unsigned char*>(bin.data()), bin.size());
    const std::string good(entry.begin(), entry.end());
    text(kc / "seed-valid.bin", good);
    text(kc / "seed-empty-binary.bin", [] {
      const auto e = encode_kernel_cache_entry(nullptr, 0);
      return std::string(e.begin(), e.end());
    }());
    text(kc / "seed-truncated.bin", good.substr(0, good.size() / 2));
    text(kc / "seed-header-only.bin", good.substr(0, kKernelCacheHeaderBytes));
    text(kc / "seed-short.bin", good.substr(0, 10));
    text(kc / "seed-wrong-magic.bin", "QDOKBIN2" + good.substr(8));
    std::string flipped = good;
    flipped[flipped.size() - 3] ^= 0x10;
    text(kc / "seed-wrong-hash.bin", flipped);
    text(kc / "seed-padded.bin", good + '\0');
    text(kc / "seed-bare-binary.bin", bin);  // as qdo wrote entries before the header
    // ---- run folders (config.json, checkpoint.h5, log.csv joined by fuzz::kFileSeparator), as
    // `qdo design` writes them for a 16 x 16 qdo+a run at 4 levels, stopped at step 3 of 6.
    const fs::path rf = dir("run_folder");
    const fs::path tmp = rf / "tmp-checkpoint.h5";
    DesignRunOptions ro;
    ro.cfg = preset_config("small");
    ro.cfg.n = 16;
    ro.cfg.padding_px = 4;
    ro.cfg.bands = 3;
    ro.cfg.wavelength_start_nm = 450;
    ro.cfg.wavelength_step_nm = 50;
    ro.cfg.sensor_distance_m = 0.0125 * 16 / 256;
    ro.cfg.srf_interpolate = true;
    ro.cfg.validate();
    ro.design.mode = DesignMode::QDOA;
    ro.design.quantizer.levels = 4;
    ro.design.steps_per_epoch = 2;
    ro.design.t0_epochs = 1;
    ro.design.t1_epochs = 2;
    ro.objective = Objective::PsfTarget;
    ro.target = target_spec_from_string("lens:500");
    ro.epochs = 3;
    ro.checkpoint_every = 3;
    const std::string cfg_json = design_run_options_to_json(ro) + "\n";
    auto checkpoint = [&](std::size_t nw, std::size_t nl, long step) {
      DesignState st;
      st.w = ramp(nw, 0.5);
      st.offsets = std::vector<double>(nl, 0.0);
      for (std::size_t l = 1; l < nl; ++l) st.offsets[l] = 0.01 * double(l);
      st.adam_w.m = ramp(nw, 1e-3);
      st.adam_w.v = ramp(nw, 1e-6);
      st.adam_w.t = step;
      st.adam_a.m = std::vector<double>(nl, 1e-4);
      st.adam_a.v = std::vector<double>(nl, 1e-8);
      st.adam_a.t = step;
      st.step = step;
      save_checkpoint(tmp.string(), st);
      std::ifstream in(tmp, std::ios::binary);
      std::string b((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      fs::remove(tmp);
      return b;
    };
    const std::size_t nw = parameter_count(ro.design.parameterization, ro.cfg.n);
    const std::string ckpt = checkpoint(nw, 4, 3);
    const std::string log =
        "step,loss,loss_aq,alpha,lr,step_s,level_heights_nm\n"
        "1,0.8123,0,0,0.01,0.02,0;300;600;900\n2,0.7011,0,0,0.01,0.02,0;301;601;899\n"
        "3,0.6502,0,0.5,0.01,0.02,0;302;602;898\n4,0.6,0,1,0.01,0.02,0;303;603;897\n";  // row 4: after the kill
    const std::string& S = fuzz::kFileSeparator;
    auto folder = [&](const std::string& name, const std::vector<std::string>& files) {
      std::string joined;
      for (std::size_t i = 0; i < files.size(); ++i) joined += (i ? S : "") + files[i];
      text(rf / name, joined);
    };
    folder("seed-resumable", {cfg_json, ckpt, log});
    folder("seed-no-log", {cfg_json, ckpt});
    folder("seed-no-checkpoint", {cfg_json});
    folder("seed-empty-log", {cfg_json, ckpt, ""});
    folder("seed-log-garbage", {cfg_json, ckpt, "step,loss\ngarbage\n"});
    folder("seed-log-no-header", {cfg_json, ckpt, "1,0.5\n"});
    folder("seed-ckpt-truncated", {cfg_json, ckpt.substr(0, ckpt.size() / 2), log});
    folder("seed-ckpt-wrong-size", {cfg_json, checkpoint(nw + 1, 4, 3), log});
    std::string ckpt_flip = ckpt;
    ckpt_flip[ckpt_flip.size() - 100] ^= 0x01;
    folder("seed-ckpt-flipped", {cfg_json, ckpt_flip, log});
    auto edit = [&](const std::string& from, const std::string& to) {
      std::string edited = cfg_json;
      const auto at = edited.find(from);
      if (at == std::string::npos) throw Error("seed: '" + from + "' not in config.json");
      return edited.replace(at, from.size(), to);
    };
    folder("seed-config-bad-mode", {edit("\"qdo+a\"", "\"bogus\""), ckpt, log});
    folder("seed-config-float-levels", {edit("\"levels\": 4", "\"levels\": 1e300"), ckpt, log});
    folder("seed-config-negative-epochs", {edit("\"epochs\": 3", "\"epochs\": -3"), ckpt, log});
    folder("seed-config-zero-epochs", {edit("\"epochs\": 3", "\"epochs\": 0"), ckpt, log});
    folder("seed-config-missing-data", {edit("\"data\": []", "\"data\": [\"/nonexistent/scenes\"]"), ckpt, log});
    folder("seed-config-truncated", {cfg_json.substr(0, cfg_json.size() / 2), ckpt, log});
    {  // qdo+m: the checkpoint holds k = log2(L) mask depths
      DesignRunOptions qm = ro;
      qm.design.mode = DesignMode::QDOM;
      folder("seed-qdom", {design_run_options_to_json(qm) + "\n", checkpoint(nw, 2, 3), log});
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "qdo_fuzz_seeds: %s\n", e.what());
    return 1;
  }
  std::printf("seeds written under %s\n", root.c_str());
  return 0;
}
