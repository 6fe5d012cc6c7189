#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "slproto/file_util.hpp"
#include "slproto/json_fields.hpp"

namespace slproto {
namespace {

using nlohmann::json;

// The message of the JsonFieldError `f` throws ("" if it does not throw).
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const JsonFieldError& e) {
    return e.what();
  }
  return "";
}

TEST(JsonFields, DuplicateKeysAreRefusedWithTheirPath) {
  EXPECT_EQ(error_of([] { parse_json_strict(R"({"a": 1, "a": 2})"); }), "a: duplicate key");
  EXPECT_EQ(error_of([] { parse_json_strict(R"({"camera": {"fx": 1, "fy": 2, "fx": 3}})"); }),
            "camera.fx: duplicate key");
  EXPECT_EQ(error_of([] { parse_json_strict(R"({"poses": [{"name": "a"}, {"name": "b", "name": "c"}]})"); }),
            "poses[1].name: duplicate key");
  EXPECT_EQ(error_of([] { parse_json_strict(R"({"m": [[1, 2], [3, {"k": 1, "k": 1}]]})"); }),
            "m[1][1].k: duplicate key");
  // The same key in sibling objects is not a duplicate.
  EXPECT_EQ(error_of([] { parse_json_strict(R"({"a": {"x": 1}, "b": {"x": 1}, "c": [{"x": 1}, {"x": 2}]})"); }), "");
}

TEST(JsonFields, SyntaxOverflowAndDepthAreRefused) {
  EXPECT_NE(error_of([] { parse_json_strict("{ not json"); }).find("not valid JSON"), std::string::npos);
  EXPECT_NE(error_of([] { parse_json_strict(R"({"x": 1e400})"); }).find("not valid JSON"), std::string::npos);
  EXPECT_NE(error_of([] { parse_json_strict(std::string(100, '[') + std::string(100, ']')); }).find("nested deeper"),
            std::string::npos);
  EXPECT_EQ(error_of([] { parse_json_strict(std::string(30, '[') + std::string(30, ']')); }), "");
}

TEST(JsonFields, UnknownAndMissingFieldsAreNamed) {
  const json doc = parse_json_strict(R"({"camera": {"fx": 1200, "fz": 3}})");
  EXPECT_EQ(error_of([&] {
              JsonObject top(doc, "");
              JsonObject camera = top.object("camera");
              camera.number("fx");
              camera.finish();
            }),
            "camera.fz: unknown field; did you mean fx?");
  EXPECT_EQ(error_of([&] { JsonObject(doc, "").object("camera").number("fy"); }), "camera.fy: missing");
  EXPECT_EQ(error_of([&] {
              JsonObject top(doc, "");
              top.finish();
            }),
            "camera: unknown field");
  // has() marks an optional field as known whether present or not.
  EXPECT_EQ(error_of([&] {
              JsonObject top(doc, "");
              EXPECT_TRUE(top.has("camera"));
              EXPECT_FALSE(top.has("projector"));
              top.finish();
            }),
            "");
  EXPECT_EQ(error_of([&] { JsonObject(doc["camera"]["fx"], "camera.fx"); }),
            "camera.fx: expected an object, got a number");
}

TEST(JsonFields, IntegersNeverWrap) {
  const json doc = parse_json_strict(
      R"({"port": 70000, "big": 3000000000, "negative": -1, "half": 2.5, "huge": 18446744073709551615,
          "ok": 65535, "text": "12"})");
  JsonObject r(doc, "");
  EXPECT_EQ(error_of([&] { r.integer<std::uint16_t>("port"); }), "port: 70000 is out of range (allowed 0 to 65535)");
  EXPECT_EQ(error_of([&] { r.integer<int>("big"); }),
            "big: 3000000000 is out of range (allowed -2147483648 to 2147483647)");
  EXPECT_EQ(error_of([&] { r.integer<unsigned>("negative"); }),
            "negative: -1 is out of range (allowed 0 to 4294967295)");
  EXPECT_EQ(error_of([&] { r.integer<std::int64_t>("huge"); }).substr(0, 36), "huge: 18446744073709551615 is out of");
  EXPECT_EQ(error_of([&] { r.integer<int>("half"); }), "half: expected an integer, got a number");
  EXPECT_EQ(error_of([&] { r.integer<int>("text"); }), "text: expected an integer, got a string");
  EXPECT_EQ(error_of([&] { r.integer<int>("ok", 1, 100); }), "ok: 65535 is out of range (allowed 1 to 100)");
  EXPECT_EQ(r.integer<std::uint16_t>("ok"), 65535);
  EXPECT_EQ(r.integer<std::uint64_t>("huge"), 18446744073709551615ULL);
  int port = 7;
  EXPECT_FALSE(r.read("absent", port));
  EXPECT_EQ(port, 7);
  EXPECT_NE(error_of([&] { r.read("port", port, 0, 1000); }), "");
}

TEST(JsonFields, NumbersChoicesAndArrays) {
  const json doc = parse_json_strict(
      R"({"gain": 2.5, "axis": "diagonal", "R": [1, 0, 0, 0, 1, 0, 0, 0], "flag": 1,
          "poses": [{"name": "a"}, {"name": 3}], "f": 1e300})");
  JsonObject r(doc, "");
  EXPECT_DOUBLE_EQ(r.number("gain", 0, 10), 2.5);
  EXPECT_EQ(error_of([&] { r.number("gain", 0, 1); }), "gain: 2.5 is out of range (allowed 0.0 to 1.0)");
  EXPECT_EQ(error_of([&] { r.number("gain", 3); }), "gain: 2.5 is out of range (allowed at least 3.0)");
  enum class Axis { columns, rows };
  EXPECT_EQ(error_of([&] {
              r.choice<Axis>("axis", {{"columns", Axis::columns}, {"rows", Axis::rows}});
            }),
            "axis: expected \"columns\" or \"rows\", got \"diagonal\"");
  EXPECT_EQ(error_of([&] { r.numbers<9>("R"); }), "R: expected 9 elements, got 8");
  EXPECT_EQ(error_of([&] { r.boolean("flag"); }), "flag: expected true or false, got a number");
  const JsonArray poses = r.array("poses", 1);
  EXPECT_EQ(poses.object(0).text("name"), "a");
  EXPECT_EQ(error_of([&] { poses.object(1).text("name"); }), "poses[1].name: expected a string, got a number");
  float f = 0;
  EXPECT_NE(error_of([&] { r.read("f", f); }).find("out of range"), std::string::npos) << "1e300 into a float";
}

TEST(JsonFields, ReadJsonTurnsErrorsIntoResultsNamingTheOrigin) {
  auto ok = read_json(R"({"n": 3})", "a.json", [](const json& doc) {
    JsonObject r(doc, "");
    const int n = r.integer<int>("n");
    r.finish();
    return n;
  });
  ASSERT_TRUE(ok.ok());
  EXPECT_EQ(*ok, 3);
  auto bad = read_json(R"({"n": 3, "m": 4})", "a.json", [](const json& doc) {
    JsonObject r(doc, "");
    const int n = r.integer<int>("n");
    r.finish();
    return n;
  });
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, Errc::malformed);
  EXPECT_EQ(bad.error().message, "a.json: m: unknown field");
}

TEST(FileUtil, AtomicWriteAndBoundedRead) {
  const auto dir = std::filesystem::temp_directory_path() / ("slscan_file_util_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "f.txt").string();
  ASSERT_TRUE(write_file_atomically(path, "hello").ok());
  auto text = read_whole_file(path);
  ASSERT_TRUE(text.ok()) << text.error().message;
  EXPECT_EQ(*text, "hello");
  auto small = read_whole_file(path, 3);
  ASSERT_FALSE(small.ok());
  EXPECT_EQ(small.error().code, Errc::oversized);
  auto missing = read_whole_file((dir / "nope").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("(errno 2)"), std::string::npos) << missing.error().message;
  EXPECT_FALSE(read_whole_file(dir.string()).ok());
  auto unwritable = write_file_atomically((dir / "no" / "such" / "dir").string(), "x");
  ASSERT_FALSE(unwritable.ok());
  EXPECT_EQ(unwritable.error().code, Errc::io_error);
  int files = 0;
  for ([[maybe_unused]] const auto& entry : std::filesystem::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 1) << "no temporary left behind";
  std::filesystem::remove_all(dir);
  EXPECT_EQ(errno_text(28), std::string(std::strerror(28)) + " (errno 28)");
}

}  // namespace
}  // namespace slproto
