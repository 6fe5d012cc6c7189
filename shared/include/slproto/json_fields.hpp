// The one strict JSON reader every parser in slscan uses (calibration files, capture manifests,
// scene files, configs, import descriptions). What it guarantees, so no parser has to:
//   - syntax errors, numbers beyond double and nesting deeper than 64 are refused;
//   - a key given twice in one object is refused with its path ("camera.fx: duplicate key");
//   - a key nobody read is refused by finish() ("camera.fz: unknown field");
//   - every error names the field's full path ("projectors.left.intrinsics.width: ...");
//   - integers are range-checked against the caller's bounds and the target type, so a value
//     never wraps (70000 into a uint16_t, 3e9 into an int, -1 into an unsigned);
//   - numbers are finite, optionally within [min, max].
// Errors are thrown as JsonFieldError inside a parser; every parser catches it at its own
// boundary and turns it into its error type (slproto: Result/Status; host: IoError, ...),
// prefixed with the file's name. read_json() does that for Result-returning parsers.
#pragma once

#include <array>
#include <concepts>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "slproto/result.hpp"

namespace slproto {

class JsonFieldError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Parses `text` with the guarantees above (duplicates, depth, number overflow). Throws
// JsonFieldError: "not valid JSON (...)" or "<path>: duplicate key".
nlohmann::json parse_json_strict(std::string_view text);

// "a.b" + "c" -> "a.b.c"; "" + "c" -> "c".
std::string json_path(std::string_view parent, std::string_view key);

class JsonArray;

// One JSON object being read. Required readers throw when the key is missing; optional
// readers (`read`) leave `out` unchanged and return false. Every key read (or asked about
// with has()) is recorded; finish() refuses the rest.
class JsonObject {
 public:
  // `path` names this object in messages ("" for the top level). Throws unless an object.
  JsonObject(const nlohmann::json& node, std::string path);

  const std::string& path() const { return path_; }
  std::string path_of(std::string_view key) const { return json_path(path_, key); }
  // Records the key as known (an optional field that may be absent) and says if present.
  bool has(std::string_view key);
  // The raw value (marked as read), for a field with a shape of its own. Throws if missing.
  const nlohmann::json& value(std::string_view key);

  double number(std::string_view key,  //
                double min = -std::numeric_limits<double>::infinity(),
                double max = std::numeric_limits<double>::infinity());
  template <std::integral T>
  T integer(std::string_view key, T min = std::numeric_limits<T>::min(), T max = std::numeric_limits<T>::max());
  bool boolean(std::string_view key);
  std::string text(std::string_view key);
  // One of the listed names; the error lists them all.
  template <class E>
  E choice(std::string_view key, std::initializer_list<std::pair<const char*, E>> names);
  template <std::size_t N>
  std::array<double, N> numbers(std::string_view key);
  std::vector<double> numbers(std::string_view key, std::size_t min_count, std::size_t max_count);
  JsonObject object(std::string_view key);
  JsonArray array(std::string_view key, std::size_t min_count = 0,
                  std::size_t max_count = std::numeric_limits<std::size_t>::max());

  // Optional fields: absent -> false and `out` untouched; present -> read as above.
  bool read(std::string_view key, double& out, double min = -std::numeric_limits<double>::infinity(),
            double max = std::numeric_limits<double>::infinity());
  bool read(std::string_view key, float& out, float min = -std::numeric_limits<float>::infinity(),
            float max = std::numeric_limits<float>::infinity());
  template <std::integral T>
  requires(!std::same_as<T, bool>) bool read(std::string_view key, T& out, T min = std::numeric_limits<T>::min(),
                                             T max = std::numeric_limits<T>::max()) {
    if (!has(key)) return false;
    out = integer<T>(key, min, max);
    return true;
  }
  bool read(std::string_view key, bool& out);
  bool read(std::string_view key, std::string& out);
  bool read(std::string_view key, std::vector<double>& out);  // any length, finite numbers

  // Throws "<path>.<key>: unknown field" for the first key not read.
  void finish() const;

  [[noreturn]] void fail(std::string_view key, const std::string& what) const;

 private:
  const nlohmann::json& node_;
  std::string path_;
  std::set<std::string, std::less<>> used_;
};

// One JSON array being read; elements are named "<path>[i]".
class JsonArray {
 public:
  JsonArray(const nlohmann::json& node, std::string path);
  std::size_t size() const { return node_.size(); }
  const std::string& path() const { return path_; }
  std::string path_of(std::size_t i) const { return path_ + "[" + std::to_string(i) + "]"; }
  const nlohmann::json& value(std::size_t i) const { return node_.at(i); }
  JsonObject object(std::size_t i) const { return JsonObject(node_.at(i), path_of(i)); }
  double number(std::size_t i, double min = -std::numeric_limits<double>::infinity(),
                double max = std::numeric_limits<double>::infinity()) const;
  template <std::integral T>
  T integer(std::size_t i, T min = std::numeric_limits<T>::min(), T max = std::numeric_limits<T>::max()) const;
  std::string text(std::size_t i) const;

 private:
  const nlohmann::json& node_;
  std::string path_;
};

namespace json_detail {
// The integer in `v` as T, refused (never wrapped) outside [min, max]. `where` names it.
std::int64_t integer_in(const nlohmann::json& v, const std::string& where, std::int64_t min, std::int64_t max);
std::uint64_t unsigned_in(const nlohmann::json& v, const std::string& where, std::uint64_t min, std::uint64_t max);
template <std::integral T>
T checked_integer(const nlohmann::json& v, const std::string& where, T min, T max) {
  if constexpr (std::is_signed_v<T>)
    return static_cast<T>(integer_in(v, where, min, max));
  else
    return static_cast<T>(unsigned_in(v, where, min, max));
}
}  // namespace json_detail

template <std::integral T>
T JsonObject::integer(std::string_view key, T min, T max) {
  static_assert(!std::same_as<T, bool>, "use boolean()");
  return json_detail::checked_integer<T>(value(key), path_of(key), min, max);
}

template <std::integral T>
T JsonArray::integer(std::size_t i, T min, T max) const {
  return json_detail::checked_integer<T>(value(i), path_of(i), min, max);
}

template <class E>
E JsonObject::choice(std::string_view key, std::initializer_list<std::pair<const char*, E>> names) {
  const std::string given = text(key);
  std::string expected;
  std::size_t n = 0;
  for (const auto& [name, e] : names) {
    if (given == name) return e;
    expected += (n == 0 ? "" : (n + 1 == names.size() ? " or " : ", "));
    expected += std::string("\"") + name + "\"";
    ++n;
  }
  fail(key, "expected " + expected + ", got \"" + given + "\"");
}

template <std::size_t N>
std::array<double, N> JsonObject::numbers(std::string_view key) {
  const std::vector<double> values = numbers(key, N, N);
  std::array<double, N> out{};
  for (std::size_t i = 0; i < N; ++i) out[i] = values[i];
  return out;
}

// Runs `read` (which reads a document with the classes above) on `text` and turns a
// JsonFieldError into Errc::malformed with "<origin>: <path>: <what>".
template <class F>
auto read_json(std::string_view text, std::string_view origin, F&& read) -> Result<decltype(read(nlohmann::json{}))> {
  try {
    return read(parse_json_strict(text));
  } catch (const JsonFieldError& e) {
    return make_error(Errc::malformed, std::string(origin) + ": " + e.what());
  }
}

}  // namespace slproto
