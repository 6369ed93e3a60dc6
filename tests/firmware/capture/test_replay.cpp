// PGM replay: frames, sequence numbers and time stamps come back exactly as written.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <span>
#include <vector>

#include "storetrack/capture/pgm.hpp"
#include "storetrack/capture/replay_frame_source.hpp"

namespace storetrack::capture {
namespace {
namespace fs = std::filesystem;

fs::path make_dir(const char* name) {
  fs::path d = fs::temp_directory_path() / (std::string(name) + std::to_string(getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::vector<std::uint8_t> pattern(int w, int h, int k) {
  std::vector<std::uint8_t> p(static_cast<std::size_t>(w * h));
  for (int i = 0; i < w * h; ++i)
    p[static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(i * 7 + k);
  return p;
}

TEST(Replay, EightBitWithTriggerFile) {
  const fs::path dir = make_dir("st_replay8_");
  const int w = 33, h = 17;
  std::ofstream csv(dir / "triggers.csv");
  csv << "file,trigger_seq,exposure_start_mono_ns,exposure_start_tai_ns,exposure_ns\n";
  for (int k = 0; k < 5; ++k) {
    auto px = pattern(w, h, k);
    frame::FrameView f;
    f.pixels = px.data();
    f.width = w;
    f.height = h;
    f.stride_bytes = w;
    // Not "f" + std::to_string(k): GCC 12 -O3 reports a -Wrestrict false positive on
    // literal + string&& (GCC bug 105329).
    const std::string name = std::string("f").append(std::to_string(k)).append(".pgm");
    ASSERT_EQ(write_pgm((dir / name).string(), f), 0);
    csv << name << "," << 100 + k << "," << 1'000'000 * k << "," << 5'000'000'000LL + k
        << ",2000\n";
  }
  csv.close();
  ReplayConfig cfg8;
  cfg8.directory = dir.string();
  ReplayFrameSource src(cfg8);
  ASSERT_EQ(src.start(), 0) << src.error();
  for (int k = 0; k < 5; ++k) {
    frame::FrameView f;
    ASSERT_EQ(src.acquire(f, 100), 0);
    EXPECT_EQ(f.sequence, 100u + k);
    EXPECT_EQ(f.timestamp_mono_ns, 1'000'000 * k);
    EXPECT_EQ(src.tai_ns(), 5'000'000'000LL + k);
    EXPECT_EQ(f.exposure_ns, 2000u);
    ASSERT_EQ(f.width, w);
    ASSERT_EQ(f.height, h);
    const auto px = pattern(w, h, k);
    EXPECT_TRUE(std::equal(px.begin(), px.end(), f.pixels));
    EXPECT_EQ(src.release(f), 0);
  }
  frame::FrameView f;
  EXPECT_EQ(src.acquire(f, 100), -ENODATA);
  fs::remove_all(dir);
}

TEST(Replay, SixteenBitWithoutTriggerFile) {
  const fs::path dir = make_dir("st_replay16_");
  const int w = 8, h = 4;
  std::vector<std::uint16_t> px(static_cast<std::size_t>(w * h));
  for (int i = 0; i < w * h; ++i)
    px[static_cast<std::size_t>(i)] = static_cast<std::uint16_t>(i * 100);
  frame::FrameView f;
  f.pixels = reinterpret_cast<const std::uint8_t*>(px.data());
  f.width = w;
  f.height = h;
  f.stride_bytes = 2 * w;
  f.format = frame::PixelFormat::kMono16;
  f.bits_per_pixel = 12;
  ASSERT_EQ(write_pgm((dir / "a.pgm").string(), f), 0);
  ASSERT_EQ(write_pgm((dir / "b.pgm").string(), f), 0);
  ReplayConfig cfg;
  cfg.directory = dir.string();
  cfg.default_period_ns = 2'500'000;
  ReplayFrameSource src(cfg);
  ASSERT_EQ(src.start(), 0) << src.error();
  EXPECT_EQ(src.size(), 2u);
  frame::FrameView g;
  ASSERT_EQ(src.acquire(g, 0), 0);
  EXPECT_EQ(g.format, frame::PixelFormat::kMono16);
  EXPECT_EQ(g.bits_per_pixel, 12);
  const auto* q = reinterpret_cast<const std::uint16_t*>(g.pixels);
  for (int i = 0; i < w * h; ++i)
    EXPECT_EQ(q[i], px[static_cast<std::size_t>(i)]);
  EXPECT_EQ(src.acquire(g, 0), -EBUSY);  // not released yet
  src.release(g);
  ASSERT_EQ(src.acquire(g, 0), 0);
  EXPECT_EQ(g.sequence, 1u);
  EXPECT_EQ(g.timestamp_mono_ns, 2'500'000);
  fs::remove_all(dir);
}

TEST(Replay, BadInputIsAClearError) {
  EXPECT_THROW(parse_trigger_csv("file,a\nx.pgm,1,2\n"), std::runtime_error);
  const std::string header =
      "file,trigger_seq,exposure_start_mono_ns,exposure_start_tai_ns,exposure_ns\n";
  EXPECT_THROW(parse_trigger_csv(header + "x.pgm,one,2,3,4\n"), std::runtime_error);
  EXPECT_THROW(parse_trigger_csv(header + "x.pgm,1,2,3\n"), std::runtime_error);
  // storetrack-sim's column names (common/sim write_frame_sequence), in its order.
  const auto sim = parse_trigger_csv(
      "frame,trigger_seq,trigger_tai_ns,reported_start_tai_ns,reported_start_mono_ns,exposure_ns,"
      "true_exposure_start_tai_ns,file\n0,17,100,200,300,500000,210,frame_000000.pgm\n");
  ASSERT_EQ(sim.size(), 1u);
  EXPECT_EQ(sim[0].file, "frame_000000.pgm");
  EXPECT_EQ(sim[0].trigger_seq, 17u);
  EXPECT_EQ(sim[0].exposure_start_tai_ns, 200);
  EXPECT_EQ(sim[0].exposure_start_mono_ns, 300);
  EXPECT_EQ(sim[0].exposure_ns, 500000u);
  ReplayConfig missing;
  missing.directory = "/nonexistent/dir";
  ReplayFrameSource src(missing);
  EXPECT_EQ(src.start(), -ENOENT);
  EXPECT_NE(src.error().find("/nonexistent/dir"), std::string::npos);
  PgmHeader h;
  const std::uint8_t truncated[] = {'P', '5', '\n', '4', ' ', '4', '\n', '2', '5', '5', '\n', 1, 2};
  EXPECT_EQ(parse_pgm_header(truncated, h), -EINVAL);
}

TEST(Replay, TriggerNumbersAreWholeIntegersAsWritten) {
  // Before: std::stoll/stoul took "5M-P10000000" as 5 (found by fuzz_trigger_csv), "-1" as
  // trigger 4294967295 and 4294967296 as trigger 0.
  const std::string header =
      "file,trigger_seq,exposure_start_mono_ns,exposure_start_tai_ns,exposure_ns\n";
  for (const char* line :
       {"a.pgm,101,10000000,5M-P10000000,2000\r\n", "a.pgm,-1,0,0,2000\n",
        "a.pgm,4294967296,0,0,2000\n", "a.pgm,1,-5,0,2000\n", "a.pgm,1,0,0, 2000\n",
        "a.pgm,1,0,0,\n", "a.pgm,1,0x10,0,2000\n", "a.pgm,1,9223372036854775808,0,2000\n"}) {
    EXPECT_THROW(parse_trigger_csv(header + line), std::runtime_error) << line;
  }
  const auto extremes =
      parse_trigger_csv(header + "a.pgm,4294967295,9223372036854775807,0," + "4294967295\n");
  ASSERT_EQ(extremes.size(), 1u);
  EXPECT_EQ(extremes[0].trigger_seq, 4294967295u);
  EXPECT_EQ(extremes[0].exposure_start_mono_ns, INT64_MAX);
  EXPECT_EQ(extremes[0].exposure_ns, 4294967295u);
}

TEST(Replay, LoopOfAReplayAtTheEndOfTimeSaturates) {
  // The loop adds the replay's span to the recorded times: with a time stamp at INT64_MAX the
  // sum overflowed (undefined behaviour); it stays at INT64_MAX.
  const fs::path dir = make_dir("st_replay_end_");
  const std::uint8_t px[4] = {1, 2, 3, 4};
  frame::FrameView f;
  f.pixels = px;
  f.width = 2;
  f.height = 2;
  f.stride_bytes = 2;
  ASSERT_EQ(write_pgm((dir / "a.pgm").string(), f), 0);
  std::ofstream(dir / "triggers.csv")
      << "file,trigger_seq,exposure_start_mono_ns,exposure_start_tai_ns,exposure_ns\n"
      << "a.pgm,1,0,0,1000\na.pgm,2,9223372036854775807,9223372036854775807,1000\n";
  ReplayConfig config;
  config.directory = dir.string();
  config.loop = true;
  ReplayFrameSource src(config);
  ASSERT_EQ(src.start(), 0) << src.error();
  std::vector<std::int64_t> times;
  for (int k = 0; k < 4; ++k) {
    frame::FrameView g;
    ASSERT_EQ(src.acquire(g, 0), 0);
    times.push_back(g.timestamp_mono_ns);
    src.release(g);
  }
  EXPECT_EQ(times, (std::vector<std::int64_t>{0, INT64_MAX, INT64_MAX, INT64_MAX}));
  fs::remove_all(dir);
}

TEST(Replay, SixteenBitPixelAboveMaxvalIsRefused) {
  // Found by fuzz_replay_pgm: maxval 4095 (12 significant bits) and a pixel 0x3634 = 13876.
  // Before: the frame said 12 bits and held a 14-bit value; netpbm allows [0, maxval].
  const fs::path dir = make_dir("st_replay_maxval_");
  const std::uint8_t file[] = {'P',  '5',  '\n', '4',  ' ',  '3',  '\n', '4',  '0',
                               '9',  '5',  '\n', 0x00, 0x00, 0x01, 0x2c, 0x02, 0x58,
                               0x03, 0x84, 0x04, 0xb0, 0x05, 0xdc, 0x07, 0x08, 0x36,
                               0x34, 0x09, 0x60, 0x0a, 0x8c, 0x0b, 0xb8, 0x0c, 0xe4};
  std::ofstream(dir / "a.pgm", std::ios::binary)
      .write(reinterpret_cast<const char*>(file), sizeof file);
  ReplayConfig config;
  config.directory = dir.string();
  ReplayFrameSource src(config);
  ASSERT_EQ(src.start(), 0) << src.error();
  frame::FrameView g;
  EXPECT_EQ(src.acquire(g, 0), -EINVAL);
  fs::remove_all(dir);
}

TEST(Replay, HeaderCommentEndsAtACarriageReturn) {
  // netpbm: a comment runs to the next CR or LF. Found by fuzz_replay_pgm: "P5" "5\r\r2\r\r#\r"
  // "...1\r\r": width 5, height 2, maxval 1; before, the comment ran to the next LF and took
  // the maxval with it.
  const std::string text = "P5 #comment\r3 2 # and another\r255\n\x01\x02\x03\x04\x05\x06";
  PgmHeader h;
  ASSERT_EQ(parse_pgm_header(
                std::span(reinterpret_cast<const std::uint8_t*>(text.data()), text.size()), h),
            0);
  EXPECT_EQ(h.width, 3);
  EXPECT_EQ(h.height, 2);
  EXPECT_EQ(h.maxval, 255);
  EXPECT_EQ(h.data_offset, text.size() - 6);
}

}  // namespace
}  // namespace storetrack::capture
