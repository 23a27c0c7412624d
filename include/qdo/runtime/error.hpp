// Errors. Every rejection of user input names the argument, the value and what is allowed.
#pragma once
#include <sstream>
#include <stdexcept>
#include <string>

namespace qdo {

// Base class for all qdo errors.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Bad user input (configuration, arguments, files). Thrown before any work starts.
class InputError : public Error {
 public:
  using Error::Error;
};

// A configuration that cannot be simulated accurately (under-sampling, precision loss),
// raised only when the user asked for strict checking.
class AccuracyError : public Error {
 public:
  using Error::Error;
};

// A result that is not finite (NaN or Inf) where it was about to be written or used: refused
// as an inaccurate computation is (CLI exit code 3), naming the output and the count.
class NumericalError : public AccuracyError {
 public:
  using AccuracyError::AccuracyError;
};

// OpenCL runtime failure (build failure, out of memory, missing fp64, no platform).
class DeviceError : public Error {
 public:
  using Error::Error;
};

template <typename T>
std::string to_str(const T& v) {
  std::ostringstream os;
  os.precision(10);
  os << v;
  return os.str();
}

// "argument 'name' = value: what is allowed"
template <typename T>
[[noreturn]] void reject(const std::string& name, const T& value, const std::string& allowed) {
  throw InputError("argument '" + name + "' = " + to_str(value) + ": " + allowed);
}

}  // namespace qdo
