#include "qdo/decode/decoder_registry.hpp"

#include <cctype>
#include <mutex>
#include <utility>

#include "qdo/runtime/error.hpp"

namespace qdo {

// The built-in decoders, one line each: NAME_decoder_entry() is defined in decoder_NAME.cpp. (A
// table rather than self-registration: qdo_core is a static library, whose members nobody
// references would be left out of the program, and their registration with them.)
#define QDO_BUILTIN_DECODERS(X) \
  X(wiener)                     \
  X(resunet)                    \
  X(cg)

#define QDO_DECLARE_DECODER(NAME) DecoderEntry NAME##_decoder_entry();
QDO_BUILTIN_DECODERS(QDO_DECLARE_DECODER)
#undef QDO_DECLARE_DECODER

namespace {

struct Registry {
  Registry() {
#define QDO_ADD_DECODER(NAME) entries.push_back(NAME##_decoder_entry());
    QDO_BUILTIN_DECODERS(QDO_ADD_DECODER)
#undef QDO_ADD_DECODER
  }
  std::mutex mutex;
  std::vector<DecoderEntry> entries;  // the built-in ones first
};

bool valid_name(const std::string& name) {
  if (name.empty() || name.size() > 64) return false;
  for (char ch : name)
    if (!(std::islower(static_cast<unsigned char>(ch)) || std::isdigit(static_cast<unsigned char>(ch)) || ch == '-' ||
          ch == '_'))
      return false;
  return true;
}

Registry& registry() {
  static Registry r;
  return r;
}

std::string names_of(const std::vector<DecoderEntry>& entries) {
  std::string s;
  for (std::size_t i = 0; i < entries.size(); ++i)
    s += (i == 0 ? "" : i + 1 == entries.size() ? " or " : ", ") + entries[i].name;
  return s;
}

}  // namespace

void register_decoder(DecoderEntry entry) {
  if (!valid_name(entry.name)) reject("decoder name", entry.name, "1 to 64 lower-case letters, digits, '-' or '_'");
  if (!entry.make && !entry.train) reject("decoder", entry.name, "an entry with a factory (make, or train for a trained decoder)");
  if (entry.trained != bool(entry.train))
    reject("decoder", entry.name,
           entry.train ? "trained = true with a train factory (it is trained with the optics)"
                       : "a train factory with trained = true (a decoder trained with the optics is made by it)");
  if (!entry.make) {  // a trained decoder at evaluation: the run's state in inference mode
    const std::string name = entry.name;
    entry.make = [name](const DecoderInputs& in) -> std::unique_ptr<Decoder> {
      if (!in.run_network)
        reject("decoder", in.spec.to_string(), "a decoder built from the camera (" + name + " is trained with the optics: qdo eval RUN)");
      return std::make_unique<NetworkImageDecoder>(in.run_network(), in.psf.planes, 8,
                                                   "the run's trained decoder (" + in.spec.to_string() + ", inference mode)");
    };
  }
  Registry& r = registry();
  const std::lock_guard<std::mutex> lock(r.mutex);
  for (const DecoderEntry& e : r.entries)
    if (e.name == entry.name)
      reject("decoder name", entry.name, "a name not registered yet (known: " + names_of(r.entries) + ")");
  r.entries.push_back(std::move(entry));
}

DecoderRegistration::DecoderRegistration(DecoderEntry entry) { register_decoder(std::move(entry)); }

bool decoder_registered(const std::string& name) {
  Registry& r = registry();
  const std::lock_guard<std::mutex> lock(r.mutex);
  for (const DecoderEntry& e : r.entries)
    if (e.name == name) return true;
  return false;
}

std::vector<std::string> decoder_names() {
  Registry& r = registry();
  const std::lock_guard<std::mutex> lock(r.mutex);
  std::vector<std::string> out;
  for (const DecoderEntry& e : r.entries) out.push_back(e.name);
  return out;
}

DecoderEntry decoder_entry(const std::string& name) {
  Registry& r = registry();
  const std::lock_guard<std::mutex> lock(r.mutex);
  for (const DecoderEntry& e : r.entries)
    if (e.name == name) return e;
  reject("decoder", name, "a registered decoder: " + names_of(r.entries));
}

std::unique_ptr<Decoder> make_decoder(const DecoderInputs& in) {
  const DecoderEntry e = decoder_entry(in.spec.kind_name());
  std::unique_ptr<Decoder> d = e.make(in);
  if (!d) throw Error("internal: the factory of decoder '" + e.name + "' returned none");
  return d;
}

std::unique_ptr<NetworkDecoder> make_trained_decoder(const NetworkSettings& s) {
  const DecoderEntry e = decoder_entry(s.spec.kind_name());
  if (!e.train) reject("decoder", s.spec.to_string(), "a decoder trained with the optics (one whose registry entry can train)");
  std::unique_ptr<NetworkDecoder> d = e.train(s);
  if (!d) throw Error("internal: the train factory of decoder '" + e.name + "' returned none");
  return d;
}

bool DecoderSpec::network() const {
  if (kind == Kind::ResUNet) return true;
  if (kind == Kind::Wiener || !decoder_registered(name)) return false;
  return decoder_entry(name).trained;
}

}  // namespace qdo
