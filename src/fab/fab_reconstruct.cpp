// Reconstruction of the height map from mask bitmaps or from an export folder (manifest.json +
// GDSII). API and conventions: include/qdo/fab/fab.hpp.
#include "qdo/fab/fab.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "data/json_strict.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo::fab {

// ------------------------------------------------------------------------------------------------
// Reconstruction

namespace {

struct PlanInfo {  // what reconstruction needs, from a plan or a manifest
  Scheme scheme = Scheme::Binary;
  std::size_t n = 0;
  double top_m = 0;
  std::vector<double> depth_m;                       // per mask
  std::vector<std::pair<std::vector<int>, int>> codes;  // (sorted mask set, level index) of used levels
  std::vector<double> level_height_m;
};

Reconstruction reconstruct_info(const PlanInfo& p, const std::vector<std::vector<std::uint8_t>>& drawn) {
  const std::size_t n = p.n, K = p.depth_m.size();
  if (drawn.size() != K) reject("masks", drawn.size(), "one bitmap per mask (" + std::to_string(K) + ")");
  for (const auto& d : drawn)
    if (d.size() != n * n) reject("mask bitmap size", d.size(), "N x N = " + std::to_string(n * n));
  std::map<std::string, int> lookup;
  for (const auto& [set, l] : p.codes) {
    std::string key(K, '0');
    for (int m : set) key[std::size_t(m)] = '1';
    lookup.emplace(key, l);
  }
  Reconstruction r;
  r.height_m = Map2D(n, n);
  r.level_of_pixel.assign(n * n, -1);
  std::string key(K, '0');
  for (std::size_t i = 0; i < n * n; ++i) {
    double e = 0;
    for (std::size_t m = 0; m < K; ++m) {
      key[m] = drawn[m][i] ? '1' : '0';
      if (drawn[m][i]) e += p.depth_m[m];
    }
    r.height_m.data[i] = p.top_m - e;
    const auto it = lookup.find(key);
    if (it != lookup.end()) r.level_of_pixel[i] = it->second;
  }
  return r;
}

PlanInfo info_of(const MaskPlan& plan) {
  PlanInfo p;
  p.scheme = plan.scheme;
  p.n = plan.n;
  p.top_m = plan.top_m;
  for (const auto& m : plan.masks) p.depth_m.push_back(m.etch_depth_m);
  for (const auto& L : plan.levels) {
    p.level_height_m.push_back(L.height_m);
    if (L.pixels) {
      std::vector<int> s = L.masks;
      std::sort(s.begin(), s.end());
      p.codes.push_back({s, L.index});
    }
  }
  return p;
}

}  // namespace

Reconstruction reconstruct(const MaskPlan& plan, const std::vector<std::vector<std::uint8_t>>& drawn) {
  return reconstruct_info(info_of(plan), drawn);
}

Reconstruction reconstruct_export(const std::string& dir) {
  const fs::path mpath = fs::path(dir) / "manifest.json";
  std::ifstream f(readable_output(mpath.string()));  // its temporary name while the command's outputs are staged
  if (!f) throw InputError("file '" + mpath.string() + "': cannot open (not an export folder?)");
  json j;
  try {
    j = parse_json_strict(std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()),
                          "file '" + mpath.string() + "'");
  } catch (const json::exception& e) {
    throw InputError("file '" + mpath.string() + "': " + e.what());
  }
  PlanInfo p;
  std::int64_t pitch = 0, org = 0;
  std::map<int, std::size_t> layer_to_mask;
  std::string gds_name;
  try {
    p.scheme = scheme_from_string(j.at("scheme").get<std::string>());
    p.n = j.at("grid").at("n").get<std::size_t>();
    pitch = j.at("grid").at("pitch_nm").get<std::int64_t>();
    org = j.at("grid").at("pixel_00_corner_nm").at(0).get<std::int64_t>();
    p.top_m = j.at("blank_top_nm").get<double>() * 1e-9;
    gds_name = j.at("gds").at("file").get<std::string>();
    for (const auto& m : j.at("masks")) {
      layer_to_mask[m.at("layer").get<int>()] = p.depth_m.size();
      p.depth_m.push_back(m.at("etch_depth_nm").get<double>() * 1e-9);
    }
    for (const auto& L : j.at("levels")) {
      p.level_height_m.push_back(L.at("height_nm").get<double>() * 1e-9);
      if (L.at("pixels").get<std::size_t>() == 0) continue;
      std::vector<int> set;
      for (const auto& lay : L.at("mask_layers")) set.push_back(int(layer_to_mask.at(lay.get<int>())));
      std::sort(set.begin(), set.end());
      p.codes.push_back({set, L.at("index").get<int>()});
    }
  } catch (const json::exception& e) {
    throw InputError("file '" + mpath.string() + "': " + e.what());
  } catch (const std::out_of_range&) {
    throw InputError("file '" + mpath.string() + "': a level names a mask layer that is not in \"masks\"");
  }
  if (pitch <= 0 || p.n == 0) throw InputError("file '" + mpath.string() + "': grid n and pitch_nm must be positive");
  if (gds_name.empty() || gds_name.find('/') != std::string::npos || gds_name == "." || gds_name == "..")
    throw InputError("file '" + mpath.string() + "': gds.file = '" + gds_name + "' must name a file in the export folder");
  const gds::Library lib = gds::read(readable_output((fs::path(dir) / gds_name).string()));
  if (std::fabs(lib.db_in_metres - 1e-9) > 1e-15)
    throw InputError("GDSII '" + gds_name + "': database unit " + to_str(lib.db_in_metres) + " m, expected 1e-9 (1 nm)");
  std::vector<std::vector<gds::Polygon>> polys(p.depth_m.size());
  for (const auto& b : lib.boundaries) {
    const auto it = layer_to_mask.find(b.layer);
    if (it == layer_to_mask.end()) continue;  // marks, aperture
    gds::Polygon g;
    for (const auto& q : b.points) {
      const std::int64_t dx = q.x - org, dy = q.y - org;
      if (dx % pitch || dy % pitch)
        throw InputError("GDSII '" + gds_name + "' layer " + std::to_string(b.layer) + ": vertex (" + std::to_string(q.x) + ", " +
                         std::to_string(q.y) + ") nm is not on the pixel grid");
      g.push_back({dx / pitch, dy / pitch});
    }
    polys[it->second].push_back(std::move(g));
  }
  std::vector<std::vector<std::uint8_t>> drawn;
  for (const auto& pl : polys) drawn.push_back(gds::rasterize(pl, p.n, p.n));
  return reconstruct_info(p, drawn);
}

}  // namespace qdo::fab
