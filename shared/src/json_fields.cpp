#include "slproto/json_fields.hpp"

#include <algorithm>
#include <cmath>

namespace slproto {

using nlohmann::json;

namespace {

constexpr int kMaxDepth = 64;

// Where the parser is, for naming a duplicate key: one frame per open object or array.
struct Frame {
  bool is_object = false;
  std::set<std::string> keys;  // objects: the keys seen so far
  std::string key;             // objects: the key whose value is being read
  std::size_t elements = 0;    // arrays: elements begun so far
};

std::string path_of(const std::vector<Frame>& frames) {
  std::string path;
  for (const Frame& f : frames) {
    if (f.is_object)
      path = json_path(path, f.key);
    else
      path += "[" + std::to_string(f.elements == 0 ? 0 : f.elements - 1) + "]";
  }
  return path;
}

const char* type_name(const json& v) {
  if (v.is_object()) return "an object";
  if (v.is_array()) return "an array";
  if (v.is_string()) return "a string";
  if (v.is_boolean()) return "true/false";
  if (v.is_null()) return "null";
  return "a number";
}

}  // namespace

std::string json_path(std::string_view parent, std::string_view key) {
  if (parent.empty()) return std::string(key);
  std::string out(parent);
  out += '.';
  out += key;
  return out;
}

json parse_json_strict(std::string_view text) {
  std::vector<Frame> frames;
  auto callback = [&](int depth, json::parse_event_t event, json& parsed) {
    if (depth > kMaxDepth) throw JsonFieldError("nested deeper than " + std::to_string(kMaxDepth) + " levels");
    const bool starts_value = event == json::parse_event_t::object_start || event == json::parse_event_t::array_start ||
                              event == json::parse_event_t::value;
    if (starts_value && !frames.empty() && !frames.back().is_object) ++frames.back().elements;
    switch (event) {
      case json::parse_event_t::object_start:
        frames.push_back(Frame{true, {}, {}, 0});
        break;
      case json::parse_event_t::array_start:
        frames.push_back(Frame{false, {}, {}, 0});
        break;
      case json::parse_event_t::object_end:
      case json::parse_event_t::array_end:
        if (!frames.empty()) frames.pop_back();
        break;
      case json::parse_event_t::key: {
        Frame& f = frames.back();
        f.key = parsed.get<std::string>();
        if (!f.keys.insert(f.key).second) throw JsonFieldError(path_of(frames) + ": duplicate key");
        break;
      }
      case json::parse_event_t::value:
        break;
    }
    return true;
  };
  try {
    return json::parse(text.begin(), text.end(), callback);
  } catch (const json::exception& e) {  // parse_error; out_of_range for a number beyond double
    throw JsonFieldError(std::string("not valid JSON (") + e.what() + ")");
  }
}

// ---------------------------------------------------------------- integers

namespace json_detail {

std::int64_t integer_in(const json& v, const std::string& where, std::int64_t min, std::int64_t max) {
  const std::string range = " (allowed " + std::to_string(min) + " to " + std::to_string(max) + ")";
  if (!v.is_number_integer()) throw JsonFieldError(where + ": expected an integer, got " + type_name(v));
  if (v.is_number_unsigned() && v.get<std::uint64_t>() > static_cast<std::uint64_t>(max))
    throw JsonFieldError(where + ": " + std::to_string(v.get<std::uint64_t>()) + " is out of range" + range);
  const auto value = v.get<std::int64_t>();
  if (value < min || value > max)
    throw JsonFieldError(where + ": " + std::to_string(value) + " is out of range" + range);
  return value;
}

std::uint64_t unsigned_in(const json& v, const std::string& where, std::uint64_t min, std::uint64_t max) {
  const std::string range = " (allowed " + std::to_string(min) + " to " + std::to_string(max) + ")";
  if (!v.is_number_integer()) throw JsonFieldError(where + ": expected an integer, got " + type_name(v));
  if (!v.is_number_unsigned()) {  // negative (nlohmann stores non-negative integers as unsigned)
    throw JsonFieldError(where + ": " + std::to_string(v.get<std::int64_t>()) + " is out of range" + range);
  }
  const auto value = v.get<std::uint64_t>();
  if (value < min || value > max)
    throw JsonFieldError(where + ": " + std::to_string(value) + " is out of range" + range);
  return value;
}

}  // namespace json_detail

namespace {

double checked_number(const json& v, const std::string& where, double min, double max) {
  if (!v.is_number()) throw JsonFieldError(where + ": expected a number, got " + type_name(v));
  const double value = v.get<double>();
  if (!std::isfinite(value)) throw JsonFieldError(where + ": not a finite number");
  if (value < min || value > max) {
    std::string range = min == -std::numeric_limits<double>::infinity() ? ("at most " + json(max).dump())
                        : max == std::numeric_limits<double>::infinity()
                            ? ("at least " + json(min).dump())
                            : (json(min).dump() + " to " + json(max).dump());
    throw JsonFieldError(where + ": " + json(value).dump() + " is out of range (allowed " + range + ")");
  }
  return value;
}

std::string checked_text(const json& v, const std::string& where) {
  if (!v.is_string()) throw JsonFieldError(where + ": expected a string, got " + type_name(v));
  return v.get<std::string>();
}

}  // namespace

// ---------------------------------------------------------------- JsonObject

JsonObject::JsonObject(const json& node, std::string path) : node_(node), path_(std::move(path)) {
  if (!node_.is_object())
    throw JsonFieldError((path_.empty() ? std::string("top level") : path_) + ": expected an object, got " +
                         type_name(node_));
}

void JsonObject::fail(std::string_view key, const std::string& what) const {
  throw JsonFieldError(path_of(key) + ": " + what);
}

bool JsonObject::has(std::string_view key) {
  used_.emplace(key);
  return node_.find(key) != node_.end();
}

const json& JsonObject::value(std::string_view key) {
  used_.emplace(key);
  const auto it = node_.find(key);
  if (it == node_.end()) fail(key, "missing");
  return *it;
}

double JsonObject::number(std::string_view key, double min, double max) {
  return checked_number(value(key), path_of(key), min, max);
}

bool JsonObject::boolean(std::string_view key) {
  const json& v = value(key);
  if (!v.is_boolean()) fail(key, std::string("expected true or false, got ") + type_name(v));
  return v.get<bool>();
}

std::string JsonObject::text(std::string_view key) { return checked_text(value(key), path_of(key)); }

std::vector<double> JsonObject::numbers(std::string_view key, std::size_t min_count, std::size_t max_count) {
  const JsonArray a = array(key, min_count, max_count);
  std::vector<double> out(a.size());
  for (std::size_t i = 0; i < a.size(); ++i) out[i] = a.number(i);
  return out;
}

JsonObject JsonObject::object(std::string_view key) { return JsonObject(value(key), path_of(key)); }

JsonArray JsonObject::array(std::string_view key, std::size_t min_count, std::size_t max_count) {
  JsonArray a(value(key), path_of(key));
  if (a.size() < min_count || a.size() > max_count) {
    const std::string count = min_count == max_count ? std::to_string(min_count)
                              : max_count == std::numeric_limits<std::size_t>::max()
                                  ? "at least " + std::to_string(min_count)
                                  : std::to_string(min_count) + " to " + std::to_string(max_count);
    fail(key, "expected " + count + " elements, got " + std::to_string(a.size()));
  }
  return a;
}

bool JsonObject::read(std::string_view key, double& out, double min, double max) {
  if (!has(key)) return false;
  out = number(key, min, max);
  return true;
}

bool JsonObject::read(std::string_view key, float& out, float min, float max) {
  if (!has(key)) return false;
  const double lowest = std::isinf(min) ? -static_cast<double>(std::numeric_limits<float>::max()) : min;
  const double highest = std::isinf(max) ? static_cast<double>(std::numeric_limits<float>::max()) : max;
  out = static_cast<float>(number(key, lowest, highest));
  return true;
}

bool JsonObject::read(std::string_view key, bool& out) {
  if (!has(key)) return false;
  out = boolean(key);
  return true;
}

bool JsonObject::read(std::string_view key, std::string& out) {
  if (!has(key)) return false;
  out = text(key);
  return true;
}

bool JsonObject::read(std::string_view key, std::vector<double>& out) {
  if (!has(key)) return false;
  out = numbers(key, 0, std::numeric_limits<std::size_t>::max());
  return true;
}

namespace {

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

// The known key a misspelt one most likely meant: the nearest by edit distance (at most a third
// of its length, and 2 at least, keeping one letter of each: "m" never suggests "n"), or one it
// begins or ends with ("offset_radians" -> offset_rad).
std::string did_you_mean(std::string_view unknown, const std::set<std::string, std::less<>>& known) {
  std::string best;
  std::size_t best_distance = std::max<std::size_t>(2, unknown.size() / 3) + 1;
  for (const auto& key : known) {
    std::size_t d = edit_distance(unknown, key);
    if (key.size() >= 3 && (unknown.starts_with(key) || key.starts_with(unknown))) d = std::min<std::size_t>(d, 1);
    if (d >= unknown.size() || d >= key.size()) continue;
    if (d < best_distance) {
      best_distance = d;
      best = key;
    }
  }
  return best;
}

}  // namespace

void JsonObject::finish() const {
  for (auto it = node_.begin(); it != node_.end(); ++it)
    if (used_.find(it.key()) == used_.end()) {
      const std::string suggestion = did_you_mean(it.key(), used_);
      fail(it.key(), suggestion.empty() ? "unknown field" : "unknown field; did you mean " + suggestion + "?");
    }
}

// ---------------------------------------------------------------- JsonArray

JsonArray::JsonArray(const json& node, std::string path) : node_(node), path_(std::move(path)) {
  if (!node_.is_array()) throw JsonFieldError(path_ + ": expected an array, got " + type_name(node_));
}

double JsonArray::number(std::size_t i, double min, double max) const {
  return checked_number(value(i), path_of(i), min, max);
}

std::string JsonArray::text(std::size_t i) const { return checked_text(value(i), path_of(i)); }

}  // namespace slproto
