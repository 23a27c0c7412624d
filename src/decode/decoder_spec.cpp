#include "qdo/decode/decoder_spec.hpp"

#include <cctype>
#include <cmath>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

std::string DecoderSpec::kind_name() const {
  if (kind == Kind::Wiener) return "wiener";
  if (kind == Kind::ResUNet) return "resunet";
  return name;
}

std::string DecoderSpec::param(const std::string& key, const std::string& def) const {
  for (const auto& [k, v] : params)
    if (k == key) return v;
  return def;
}

std::string DecoderSpec::to_string() const {
  if (kind == Kind::Wiener) return "wiener";
  if (kind == Kind::ResUNet) return "resunet:depth=" + std::to_string(depth) + ",root=" + std::to_string(root);
  std::string s = name;
  for (std::size_t i = 0; i < params.size(); ++i) s += (i ? "," : ":") + params[i].first + "=" + params[i].second;
  return s;
}

namespace {

std::size_t parse_count(const std::string& key, const std::string& value, std::size_t lo, std::size_t hi) {
  bool digits = !value.empty() && value.size() <= 6;
  for (char ch : value) digits = digits && std::isdigit(static_cast<unsigned char>(ch));
  const std::size_t v = digits ? std::stoul(value) : 0;
  if (!digits || v < lo || v > hi)
    reject("--decoder resunet key '" + key + "'", value, "an integer from " + std::to_string(lo) + " to " + std::to_string(hi));
  return v;
}

// "wiener, resunet, resunet:paper or resunet:depth=D,root=R", then the other registered names.
std::string known_specs() {
  std::string others;
  for (const std::string& n : decoder_names())
    if (n != "wiener" && n != "resunet") others += ", " + n;
  if (others.empty()) return "wiener, resunet, resunet:paper or resunet:depth=D,root=R";
  return "wiener, resunet, resunet:paper, resunet:depth=D,root=R" + others + " (NAME:key=value,... with parameters)";
}

bool name_char(char ch) {
  return std::islower(static_cast<unsigned char>(ch)) || std::isdigit(static_cast<unsigned char>(ch)) || ch == '-' || ch == '_';
}

DecoderSpec named_spec(const std::string& spec, const std::string& head) {
  DecoderSpec d;
  d.kind = DecoderSpec::Kind::Named;
  d.name = head;
  if (head.size() == spec.size()) return d;
  const std::string rest = spec.substr(head.size() + 1);
  if (rest.empty()) reject("--decoder", spec, head + " or " + head + ":key=value,... (nothing after ':')");
  std::size_t pos = 0;
  while (true) {
    const std::size_t comma = rest.find(',', pos);
    const std::string item = rest.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    const std::size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) reject("--decoder " + head + " option", item, "key=value");
    const std::string key = item.substr(0, eq);
    for (const auto& kv : d.params)
      if (kv.first == key) reject("--decoder " + head + " key '" + key + "'", item.substr(eq + 1), "given once");
    d.params.push_back({key, item.substr(eq + 1)});
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  // The widest layer has root x 2^(depth-1) channels (the paper's depth 7, root 32: 2048). Beyond
  // 4096 the network's weights alone exceed what any device here holds, and LibTorch fails deep
  // inside its allocator: refused here, before any work.
  const double widest = double(d.root) * std::ldexp(1.0, int(d.depth) - 1);
  if (widest > 4096)
    reject("--decoder", spec,
           "a Res-UNet whose widest layer, root x 2^(depth-1), has at most 4096 channels (this one: " + to_str(widest) + ")");
  return d;
}

}  // namespace

DecoderSpec decoder_spec_from_string(const std::string& spec) {
  DecoderSpec d;
  if (spec == "wiener") return d;
  const std::string head = spec.substr(0, spec.find(':'));
  if (head != "resunet") {
    bool ok = !head.empty();
    for (char ch : head) ok = ok && name_char(ch);
    if (!ok || head == "wiener" || !decoder_registered(head)) reject("--decoder", spec, known_specs());
    return named_spec(spec, head);
  }
  d.kind = DecoderSpec::Kind::ResUNet;
  if (spec == "resunet") return d;
  const std::string rest = spec.substr(head.size() + 1);
  if (rest == "paper") {
    d.depth = 7;
    d.root = 32;
    return d;
  }
  if (rest.empty()) reject("--decoder", spec, "resunet, resunet:paper or resunet:depth=D,root=R (nothing after ':')");
  bool seen_depth = false, seen_root = false;
  std::size_t pos = 0;
  while (pos <= rest.size()) {
    const std::size_t comma = rest.find(',', pos);
    const std::string item = rest.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    const std::size_t eq = item.find('=');
    if (eq == std::string::npos) reject("--decoder resunet option", item, "key=value with key depth or root");
    const std::string key = item.substr(0, eq), value = item.substr(eq + 1);
    if (key == "depth") {
      if (seen_depth) reject("--decoder resunet key 'depth'", value, "given once");
      d.depth = parse_count(key, value, 1, 10);
      seen_depth = true;
    } else if (key == "root") {
      if (seen_root) reject("--decoder resunet key 'root'", value, "given once");
      d.root = parse_count(key, value, 1, 1024);
      seen_root = true;
    } else {
      reject("--decoder resunet key", key, "depth or root (or the spec resunet:paper)");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  // The widest layer has root x 2^(depth-1) channels (the paper's depth 7, root 32: 2048). Beyond
  // 4096 the network's weights alone exceed what any device here holds, and LibTorch fails deep
  // inside its allocator: refused here, before any work.
  const double widest = double(d.root) * std::ldexp(1.0, int(d.depth) - 1);
  if (widest > 4096)
    reject("--decoder", spec,
           "a Res-UNet whose widest layer, root x 2^(depth-1), has at most 4096 channels (this one: " + to_str(widest) + ")");
  return d;
}

}  // namespace qdo
