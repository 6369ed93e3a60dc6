// The one strict JSON reader (common/json): every refusal carries the file, the field's path and
// the reason; unknown keys name the nearest known key; integers are JSON integers; ranges are
// stated as accepted. Expected texts are written out here, not taken from the reader.
#include "storetrack/json/strict_reader.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <string>

#include "storetrack/json/text_file.hpp"

namespace storetrack::jsonfile {
namespace {

// Runs `read` on `text` as file "f.json"; the refusal, or a failure when none is thrown.
template <typename Read>
FieldError refusal(const std::string& text, Read read) {
  const Document doc = Document::parse(text, "f.json");
  try {
    read(doc.root());
  } catch (const FieldError& e) {
    return e;
  }
  ADD_FAILURE() << text << " accepted";
  return FieldError("", "", "");
}

// A small configuration with the shape of the host's: {"aligner": {"max_wait_ms", ...}, "udp"}.
void read_config(const Value& root) {
  Object top = root.object();
  if (const auto a = top.find("aligner")) {
    Object aligner = a->object();
    double wait_ms = 10;
    aligner.get("max_wait_ms", wait_ms, Range{0, 60000, true});
    int max_pending = 64;
    aligner.get("max_pending", max_pending, 1, 4096);
    aligner.finish();
  }
  if (const auto u = top.find("udp")) {
    Object udp = u->object();
    int port = 0;
    udp.get("port", port, 0, 65535);
    std::string bind;
    udp.get("bind", bind);
    udp.finish();
  }
  top.finish();
}

TEST(StrictReader, UnknownKeysAreRefusedWithTheNearestKnownKey) {
  struct Case {
    const char* json;
    const char* path;
    const char* reason;
  };
  const Case cases[] = {
      {R"({"aligner": {"max_wait": 10}})", "aligner.max_wait",
       "unknown key (did you mean max_wait_ms?)"},
      {R"({"algner": {"max_wait_ms": 10}})", "algner", "unknown key (did you mean aligner?)"},
      {R"({"udp": {"prot": 5}})", "udp.prot", "unknown key (did you mean port?)"},
      {R"({"udp": {"bnid": "0.0.0.0"}})", "udp.bnid", "unknown key (did you mean bind?)"},
      // Nothing near: the known keys are listed instead of a guess.
      {R"({"telemetry": 1})", "telemetry", "unknown key (known keys: aligner, udp)"},
  };
  for (const Case& c : cases) {
    const FieldError e = refusal(c.json, read_config);
    EXPECT_EQ(e.file(), "f.json") << c.json;
    EXPECT_EQ(e.path(), c.path) << c.json;
    EXPECT_EQ(e.reason(), c.reason) << c.json;
    EXPECT_EQ(std::string(e.what()), std::string("f.json: ") + c.path + ": " + c.reason);
  }
  EXPECT_NO_THROW(read_config(Document::parse(R"({"aligner": {"max_wait_ms": 5}})", "f").root()));
}

TEST(StrictReader, WrongTypesAndShapesAreRefused) {
  struct Case {
    const char* json;
    const char* path;
    const char* reason;
  };
  const Case cases[] = {
      {R"([1, 2])", "(top level)", "expected an object, got an array"},
      {R"({"aligner": [1, 2]})", "aligner", "expected an object, got an array"},
      {R"({"aligner": 3})", "aligner", "expected an object, got an integer"},
      {R"({"udp": {"bind": 5}})", "udp.bind", "expected a string, got 5"},
      {R"({"aligner": {"max_wait_ms": "10"}})", "aligner.max_wait_ms",
       "expected a number in (0, 60000], got \"10\""},
      {R"({"aligner": {"max_wait_ms": null}})", "aligner.max_wait_ms",
       "expected a number in (0, 60000], got null"},
  };
  for (const Case& c : cases) {
    const FieldError e = refusal(c.json, read_config);
    EXPECT_EQ(e.path(), c.path) << c.json;
    EXPECT_EQ(e.reason(), c.reason) << c.json;
  }
  const auto three = [](const Value& root) { root.object().at("p").numbers(3); };
  EXPECT_EQ(refusal(R"({"p": [1, 2]})", three).reason(), "expected an array of 3 elements, got 2");
  EXPECT_EQ(refusal(R"({"p": [1, "2", 3]})", three).path(), "p[1]");
  EXPECT_EQ(refusal(R"({})", three).reason(), "missing");
  EXPECT_EQ(refusal(R"({})", three).path(), "p");
  EXPECT_EQ(refusal(R"({"q": [1, 2, 3]})", three).reason(), "missing (is q a typo of it?)");
}

TEST(StrictReader, IntegersMustBeJsonIntegersWithinTheirRange) {
  // 2.5 was read as 2, 4294967297 as 1 and 1e300 was undefined behaviour with nlohmann's get.
  struct Case {
    const char* json;
    const char* shown;  // as nlohmann prints it back
  };
  const Case cases[] = {{"2.5", "2.5"},
                        {"1e3", "1000.0"},
                        {"64.0", "64.0"},
                        {"true", "true"},
                        {"\"64\"", "\"64\""},
                        {"4294967297", "4294967297"},
                        {"-1", "-1"},
                        {"4097", "4097"},
                        {"18446744073709551615", "18446744073709551615"},
                        {"-9223372036854775808", "-9223372036854775808"}};
  for (const Case& c : cases) {
    const FieldError e =
        refusal(std::string(R"({"aligner": {"max_pending": )") + c.json + "}}", read_config);
    EXPECT_EQ(e.path(), "aligner.max_pending") << c.json;
    EXPECT_EQ(e.reason(), std::string("expected an integer in [1, 4096], got ") + c.shown);
  }
  const auto as_int = [](const Value& root) { root.object().at("x").as<int>(); };
  EXPECT_EQ(refusal(R"({"x": 2147483648})", as_int).reason(),
            "expected an integer in [-2147483648, 2147483647], got 2147483648");
  const auto as_u8 = [](const Value& root) { root.object().at("x").as<std::uint8_t>(); };
  EXPECT_EQ(refusal(R"({"x": -1})", as_u8).reason(), "expected an integer in [0, 255], got -1");
  const Document doc = Document::parse(
      R"({"a": 4096, "b": 1, "c": -9223372036854775808, "d": 18446744073709551615})", "f");
  Object o = doc.root().object();
  EXPECT_EQ(o.at("a").integer(1, 4096), 4096);
  EXPECT_EQ(o.at("b").integer(1, 4096), 1);
  EXPECT_EQ(o.at("c").as<std::int64_t>(), INT64_MIN);
  EXPECT_EQ(o.at("d").as<std::uint64_t>(), UINT64_MAX);
}

TEST(StrictReader, NumberRangesAreStatedAsAccepted) {
  EXPECT_EQ((Range{0, 60000, true}).text(), "(0, 60000]");
  EXPECT_EQ(Range::closed(0.1, 60).text(), "[0.1, 60]");
  EXPECT_EQ(Range::above(0).text(), "> 0");
  EXPECT_EQ(Range::at_least(0).text(), ">= 0");
  EXPECT_EQ((Range{0, 1, true, true}).text(), "(0, 1)");
  for (const char* v : {"0", "-1", "60000.001", "1e+300"}) {
    const FieldError e =
        refusal(std::string(R"({"aligner": {"max_wait_ms": )") + v + "}}", read_config);
    EXPECT_EQ(e.reason(), std::string("expected a number in (0, 60000], got ") + v) << v;
  }
  // The bounds themselves: the open one refused above, the closed one accepted.
  double wait = 0;
  const Document doc = Document::parse(R"({"w": 60000, "v": 1e-300})", "f");
  Object o = doc.root().object();
  EXPECT_TRUE(o.get("w", wait, Range{0, 60000, true}));
  EXPECT_EQ(wait, 60000);
  EXPECT_TRUE(o.get("v", wait, Range{0, 60000, true}));
  EXPECT_EQ(wait, 1e-300);
  EXPECT_FALSE(o.get("absent", wait, Range{0, 60000, true}));
  EXPECT_EQ(wait, 1e-300);  // left as it was
}

TEST(StrictReader, NotJsonIsRefusedWithTheFile) {
  for (const char* text : {"", "{", R"({"a": 1e400})", R"({"a": 1,})"}) {
    try {
      Document::parse(text, "bad.json");
      ADD_FAILURE() << text << " accepted";
    } catch (const FieldError& e) {
      EXPECT_EQ(e.file(), "bad.json");
      EXPECT_EQ(e.reason().rfind("not valid JSON: ", 0), 0u) << e.reason();
    }
  }
}

TEST(StrictReader, NearestKeyIsATypoDistanceAway) {
  const std::vector<std::string> known = {"max_wait_ms", "max_pending", "min_cameras",
                                          "max_sequence_lead"};
  EXPECT_EQ(nearest_key("max_wait", known), "max_wait_ms");     // shortened
  EXPECT_EQ(nearest_key("max_pendign", known), "max_pending");  // two letters swapped
  EXPECT_EQ(nearest_key("min_camera", known), "min_cameras");   // one letter missing
  EXPECT_EQ(nearest_key("MAX_PENDING", known), "");             // 11 edits: no guess
  EXPECT_EQ(nearest_key("colour", known), "");
  EXPECT_EQ(nearest_key("x", {}), "");
}

TEST(StrictReader, KnownKeysThatAreNotReadAreAccepted) {
  const Document doc = Document::parse(R"({"comment": "x", "a": 1})", "f");
  Object o = doc.root().object();
  o.known({"comment"});
  int a = 0;
  o.get("a", a);
  EXPECT_NO_THROW(o.finish());
  EXPECT_EQ(a, 1);
}

TEST(ReadTextFile, ReadsEveryByteAndNamesAFileItCannotOpen) {
  const std::string path = ::testing::TempDir() + "read_text_file_test.txt";
  const std::string bytes = std::string("line 1\r\nline 2\n") + '\0' + "tail";
  std::ofstream(path, std::ios::binary) << bytes;
  EXPECT_EQ(read_text_file(path), bytes);
  std::ofstream(path, std::ios::binary | std::ios::trunc).flush();
  EXPECT_EQ(read_text_file(path), "");
  std::remove(path.c_str());
  try {
    read_text_file("/nonexistent/dir/file.json");
    ADD_FAILURE() << "missing file read";
  } catch (const FileReadError& e) {
    EXPECT_EQ(std::string(e.what()),
              "/nonexistent/dir/file.json: cannot open (No such file or directory)");
  }
  try {
    read_text_file("/");
    ADD_FAILURE() << "a directory read as a file";
  } catch (const FileReadError& e) {
    EXPECT_EQ(std::string(e.what()), "/: cannot read (Is a directory)");
  }
  try {
    Document::read("/nonexistent/dir/file.json");
    ADD_FAILURE() << "missing file read";
  } catch (const FieldError& e) {
    EXPECT_EQ(std::string(e.what()),
              "/nonexistent/dir/file.json: cannot open (No such file or directory)");
  }
}

}  // namespace
}  // namespace storetrack::jsonfile
