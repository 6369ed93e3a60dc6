// CAN FD framing and host-side reassembly under loss, duplication, reordering and corruption.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <map>
#include <random>
#include <vector>

#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/canfd_linux.hpp"
#include "test_helpers.hpp"

namespace storetrack::msg {
namespace {

using Frames = std::array<CanFdFrame, kCanFdMaxFramesPerMessage>;
constexpr std::int64_t kMs = 1'000'000;

std::vector<CanFdFrame> encode(const MarkObservations& m) {
  Frames frames;
  const int n = encode_canfd(m, frames);
  EXPECT_GT(n, 0);
  return {frames.begin(), frames.begin() + std::max(n, 0)};
}

// The codec's output is deterministic, so equality of re-encoded frames is equality of content.
bool same_message(const MarkObservations& a, const MarkObservations& b) {
  const auto fa = encode(a);
  const auto fb = encode(b);
  if (fa.size() != fb.size()) return false;
  for (std::size_t i = 0; i < fa.size(); ++i) {
    if (fa[i].can_id != fb[i].can_id || fa[i].len != fb[i].len ||
        !std::equal(fa[i].data, fa[i].data + fa[i].len, fb[i].data))
      return false;
  }
  return true;
}

TEST(MsgCanFd, FramesAreSelfContainedAndValid) {
  std::mt19937_64 rng(10);
  for (int mark_count = 0; mark_count <= static_cast<int>(kMaxMarks); ++mark_count) {
    const MarkObservations m = test::random_observations(rng, mark_count);
    const auto frames = encode(m);
    const std::size_t stream =
        kMarkObservationsFixedBytes + 8u * static_cast<unsigned>(mark_count) + 4;
    ASSERT_EQ(frames.size(), (stream + 60) / 61) << mark_count;
    ASSERT_EQ(frames.size(), canfd_frame_count(m));
    for (std::size_t i = 0; i < frames.size(); ++i) {
      const CanFdFrame& f = frames[i];
      EXPECT_LE(f.can_id, canid::kMask29);
      EXPECT_EQ(canid::lcc(f.can_id), canid::kLccNoc);
      EXPECT_EQ(canid::fid(f.can_id), static_cast<std::uint8_t>(MessageId::kMarkObservations));
      EXPECT_EQ(canid::unit(f.can_id), m.unit_id);
      EXPECT_EQ(canid::camera(f.can_id), m.camera_id);
      EXPECT_EQ(canid::version(f.can_id), kMarkObservationsVersion);
      EXPECT_EQ(f.data[0], static_cast<std::uint8_t>(m.trigger_seq >> 8));
      EXPECT_EQ(f.data[1], static_cast<std::uint8_t>(m.trigger_seq));
      EXPECT_EQ(f.data[2] >> 4, static_cast<int>(i));
      EXPECT_EQ((f.data[2] & 0xF) + 1, static_cast<int>(frames.size()));
      EXPECT_EQ(f.len, canfd_round_up_len(f.len));
      if (i + 1 < frames.size()) {
        EXPECT_EQ(f.len, 64);
      }
    }
  }
  EXPECT_EQ(canfd_round_up_len(9), 12);
  EXPECT_EQ(canfd_round_up_len(38), 48);
  EXPECT_EQ(canfd_round_up_len(64), 64);
}

TEST(MsgCanFd, EncoderRefusesWhatItCannotCarry) {
  std::mt19937_64 rng(11);
  MarkObservations m = test::random_observations(rng, 23);
  Frames frames;
  EXPECT_EQ(encode_canfd(m, std::span(frames).first(3)), -ENOSPC);  // 23 marks need 4
  m.mark_count = kMaxMarks + 1;
  EXPECT_EQ(encode_canfd(m, frames), -ERANGE);
}

TEST(MsgCanFd, RoundTripInOrder) {
  std::mt19937_64 rng(12);
  CanFdReassembler reassembler;
  std::int64_t now = 0;
  for (int i = 0; i < 2000; ++i) {
    const MarkObservations m = test::random_observations(rng);
    std::optional<AnyMessage> done;
    const auto frames = encode(m);
    for (std::size_t k = 0; k < frames.size(); ++k) {
      ASSERT_EQ(reassembler.push(frames[k], now += 10'000, done), DecodeError::kNone);
      ASSERT_EQ(done.has_value(), k + 1 == frames.size());
    }
    ASSERT_TRUE(std::holds_alternative<MarkObservations>(*done));
    const auto& out = std::get<MarkObservations>(*done);
    ASSERT_EQ(out.trigger_seq, m.trigger_seq);
    ASSERT_EQ(out.exposure_start_tai_ns, m.exposure_start_tai_ns);
    ASSERT_EQ(out.mark_count, m.mark_count);
    for (std::size_t k = 0; k < m.mark_count; ++k) {
      EXPECT_LE(std::abs(out.marks[k].x_px - m.marks[k].x_px), 1.0 / 512.0 + 1e-6);
      EXPECT_LE(std::abs(out.marks[k].y_px - m.marks[k].y_px), 1.0 / 512.0 + 1e-6);
    }
    ASSERT_TRUE(same_message(out, m));  // decoded values are on the wire grid
  }
  EXPECT_EQ(reassembler.counters().completed, 2000u);
  EXPECT_EQ(reassembler.in_flight(), 0u);
}

TEST(MsgCanFd, UnitHealthRoundTrip) {
  std::mt19937_64 rng(13);
  CanFdReassembler reassembler;
  for (int i = 0; i < 200; ++i) {
    const UnitHealth h = test::random_health(rng);
    Frames frames;
    const int n = encode_canfd(h, frames);
    ASSERT_EQ(n, static_cast<int>(canfd_frame_count(h)));
    std::optional<AnyMessage> done;
    for (int k = n - 1; k >= 0; --k)  // reversed order
      ASSERT_EQ(reassembler.push(frames[static_cast<std::size_t>(k)], i * kMs, done),
                DecodeError::kNone);
    ASSERT_TRUE(done && std::holds_alternative<UnitHealth>(*done));
    const auto& out = std::get<UnitHealth>(*done);
    EXPECT_EQ(out.report_tai_ns, h.report_tai_ns);
    EXPECT_EQ(out.frames_dropped, h.frames_dropped);
    EXPECT_EQ(out.status, h.status);
    EXPECT_EQ(out.sensor_temp_cdeg, h.sensor_temp_cdeg);
  }
}

// Four cameras, many exposures, frames interleaved, shuffled within a window, duplicated and
// lost: every complete exposure is delivered exactly once and intact, every incomplete one
// times out, and the counters account for every frame.
TEST(MsgCanFd, ReassemblyToleratesLossDuplicationAndReordering) {
  std::mt19937_64 rng(14);
  struct Sent {
    MarkObservations message;
    bool complete = true;
    int delivered = 0;
    std::size_t frames_sent = 0, frames_dropped = 0;
  };
  std::map<std::pair<std::uint8_t, std::uint32_t>, Sent> sent;  // (camera, seq)
  std::vector<CanFdFrame> wire;
  std::size_t duplicated = 0;
  for (std::uint32_t seq = 1000; seq < 1400; ++seq) {
    for (std::uint8_t camera = 0; camera < 4; ++camera) {
      MarkObservations m = test::random_observations(rng);
      m.unit_id = camera / 2;
      m.camera_id = camera;
      m.trigger_seq = seq;
      Sent s{m};
      for (const CanFdFrame& f : encode(m)) {
        const double u = test::uniform(rng, 0.0, 1.0);
        if (u < 0.03) {
          s.complete = false;
          ++s.frames_dropped;
          continue;
        }
        wire.push_back(f);
        ++s.frames_sent;
        if (u > 0.95) {
          wire.push_back(f);
          ++duplicated;
        }
      }
      sent[{camera, seq}] = s;
    }
  }
  // Reorder: each frame moves by less than 24 positions (several exposures interleave).
  std::vector<std::pair<double, CanFdFrame>> keyed;
  for (std::size_t i = 0; i < wire.size(); ++i)
    keyed.emplace_back(static_cast<double>(i) + test::uniform(rng, 0.0, 24.0), wire[i]);
  std::stable_sort(keyed.begin(), keyed.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  for (std::size_t i = 0; i < wire.size(); ++i)
    wire[i] = keyed[i].second;
  CanFdReassembler reassembler;
  std::int64_t now = 0;
  for (const CanFdFrame& f : wire) {
    std::optional<AnyMessage> done;
    ASSERT_EQ(reassembler.push(f, now += 200'000, done), DecodeError::kNone);  // 200 us per frame
    if (done) {
      const auto& m = std::get<MarkObservations>(*done);
      auto it = sent.find({m.camera_id, m.trigger_seq});
      ASSERT_NE(it, sent.end());
      ASSERT_TRUE(it->second.complete);
      ++it->second.delivered;
      EXPECT_EQ(m.exposure_start_mono_ns, it->second.message.exposure_start_mono_ns);
      EXPECT_EQ(m.mark_count, it->second.message.mark_count);
    }
  }
  reassembler.expire(now + 1'000 * kMs);
  // A transfer whose every frame was lost leaves no trace at the receiver.
  std::size_t complete = 0, incomplete = 0, dropped = 0;
  for (const auto& [key, s] : sent) {
    if (s.complete) {
      EXPECT_EQ(s.delivered, 1) << int(key.first) << " " << key.second;
      ++complete;
    } else {
      EXPECT_EQ(s.delivered, 0);
      if (s.frames_sent > 0) {
        ++incomplete;
        dropped += s.frames_dropped;
      }
    }
  }
  const CanReassemblyCounters& c = reassembler.counters();
  EXPECT_EQ(c.frames, wire.size());
  EXPECT_EQ(c.completed, complete);
  EXPECT_EQ(c.timeouts + c.evictions, incomplete);
  EXPECT_EQ(c.evictions, 0u);
  EXPECT_EQ(c.duplicates, duplicated);
  EXPECT_EQ(c.fragments_lost, dropped);
  EXPECT_EQ(c.fragments_accepted + c.duplicates, c.frames);
  EXPECT_EQ(reassembler.in_flight(), 0u);
}

TEST(MsgCanFd, CorruptedFragmentIsDetectedNotDelivered) {
  std::mt19937_64 rng(15);
  std::size_t detected = 0, trials = 0;
  CanFdReassembler reassembler;
  std::int64_t now = 0;
  for (int i = 0; i < 300; ++i) {
    MarkObservations m = test::random_observations(rng, 23);
    m.trigger_seq = static_cast<std::uint32_t>(i);
    auto frames = encode(m);
    // Flip one bit in the stream part of one fragment (the CAN frame CRC would normally catch
    // this; the transfer CRC-32 is the end-to-end check, e.g. against a faulty gateway).
    CanFdFrame& victim = frames[rng() % frames.size()];
    const std::size_t stream_bytes = victim.len - kCanFdFragmentHeaderBytes;
    const std::size_t byte = kCanFdFragmentHeaderBytes + rng() % stream_bytes;
    victim.data[byte] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
    std::optional<AnyMessage> done;
    DecodeError last = DecodeError::kNone;
    for (const CanFdFrame& f : frames)
      last = reassembler.push(f, now += 10'000, done);
    ++trials;
    if (!done) {
      ++detected;
      EXPECT_NE(last, DecodeError::kNone);
    } else {
      // A flip in the last frame's padding is harmless: the message must then be intact.
      EXPECT_TRUE(same_message(std::get<MarkObservations>(*done), m));
    }
  }
  const auto& c = reassembler.counters();
  EXPECT_GT(detected, trials * 8 / 10);
  EXPECT_EQ(c.crc_errors + c.out_of_range + c.bad_length, detected);
}

TEST(MsgCanFd, FinishedTransferIsTheStreamAsReceivedValidOrNot) {
  // Raw recording of CAN FD: once a transfer's fragments are all in, its stream (the frames'
  // bytes after their 3-byte headers, in fragment order) is available, whether the transfer
  // then decodes or not; never before, never for a duplicate.
  std::mt19937_64 rng(21);
  CanFdReassembler reassembler;
  std::int64_t now = 0;
  for (int i = 0; i < 50; ++i) {
    MarkObservations m = test::random_observations(rng, 1 + i % 40);
    m.trigger_seq = static_cast<std::uint32_t>(i);
    auto frames = encode(m);
    const bool corrupt = i % 3 == 1;
    if (corrupt) frames[0].data[kCanFdFragmentHeaderBytes + 2] ^= 0x10;
    std::vector<std::uint8_t> stream;
    for (const CanFdFrame& f : frames)
      stream.insert(stream.end(), f.data + kCanFdFragmentHeaderBytes, f.data + f.len);
    std::optional<AnyMessage> done;
    for (std::size_t k = 0; k < frames.size(); ++k) {
      const DecodeError e = reassembler.push(frames[k], now += 10'000, done);
      const auto t = reassembler.finished_transfer();
      if (k + 1 < frames.size()) {
        EXPECT_FALSE(t);
        continue;
      }
      ASSERT_TRUE(t);
      EXPECT_EQ(t->can_id, frames[0].can_id);
      EXPECT_TRUE(std::equal(t->stream.begin(), t->stream.end(), stream.begin(), stream.end()));
      EXPECT_EQ(done.has_value(), !corrupt);
      EXPECT_EQ(e == DecodeError::kNone, !corrupt);
    }
    reassembler.push(frames.back(), now += 10'000, done);  // a late duplicate
    EXPECT_FALSE(reassembler.finished_transfer());
  }
}

TEST(MsgCanFd, LateDuplicatesAndSlotExhaustion) {
  std::mt19937_64 rng(16);
  CanFdReassembler reassembler;
  std::optional<AnyMessage> done;
  MarkObservations m = test::random_observations(rng, 23);
  const auto frames = encode(m);
  for (const auto& f : frames)
    reassembler.push(f, 0, done);
  ASSERT_TRUE(done);
  for (const auto& f : frames) {
    EXPECT_EQ(reassembler.push(f, 1000, done), DecodeError::kNone);
    EXPECT_FALSE(done);  // a retransmitted copy is not delivered twice
  }
  EXPECT_EQ(reassembler.counters().duplicates, frames.size());
  EXPECT_EQ(reassembler.in_flight(), 0u);
  // After the timeout the same id and 16-bit sequence is a new transfer (sequence reuse).
  for (const auto& f : frames)
    reassembler.push(f, 50 * kMs, done);
  EXPECT_TRUE(done);
  EXPECT_EQ(reassembler.counters().completed, 2u);
  // More incomplete transfers than slots: the oldest are evicted, memory stays bounded.
  const std::size_t extra = 5;
  for (std::size_t i = 0; i < CanFdReassembler::kSlots + extra; ++i) {
    m.trigger_seq = static_cast<std::uint32_t>(5000 + i);
    reassembler.push(encode(m)[0], 60 * kMs + static_cast<std::int64_t>(i), done);
  }
  EXPECT_EQ(reassembler.in_flight(), CanFdReassembler::kSlots);
  EXPECT_EQ(reassembler.counters().evictions, extra);
  reassembler.expire(200 * kMs);
  EXPECT_EQ(reassembler.counters().timeouts, CanFdReassembler::kSlots);
  EXPECT_EQ(reassembler.in_flight(), 0u);
}

TEST(MsgCanFd, MalformedFramesGetTypedErrorsAndCounters) {
  std::mt19937_64 rng(17);
  const MarkObservations m = test::random_observations(rng, 23);
  const CanFdFrame good = encode(m)[0];
  struct Case {
    const char* what;
    CanFdFrame frame;
    DecodeError expected;
  };
  std::vector<Case> cases;
  auto with = [&](const char* what, auto change, DecodeError e) {
    CanFdFrame f = good;
    change(f);
    cases.push_back({what, f, e});
  };
  with(
      "bit above 29", [](CanFdFrame& f) { f.can_id |= 1u << 29; }, DecodeError::kBadMagic);
  with(
      "other channel", [](CanFdFrame& f) { f.can_id = (f.can_id & ~(7u << 26)) | (6u << 26); },
      DecodeError::kBadMagic);
  with(
      "version 1 (an older unit)", [](CanFdFrame& f) { f.can_id = (f.can_id & ~7u) | 1u; },
      DecodeError::kBadVersion);
  with(
      "unknown message",
      [](CanFdFrame& f) { f.can_id = (f.can_id & ~(0x7Fu << 19)) | (0x55u << 19); },
      DecodeError::kUnknownType);
  with(
      "FtiSample is not a CAN message",
      [](CanFdFrame& f) { f.can_id = (f.can_id & ~(0x7Fu << 19)) | (0x10u << 19); },
      DecodeError::kUnknownType);
  with(
      "empty", [](CanFdFrame& f) { f.len = 0; }, DecodeError::kTooShort);
  with(
      "header only", [](CanFdFrame& f) { f.len = 3; }, DecodeError::kTooShort);
  with(
      "not a CAN FD length", [](CanFdFrame& f) { f.len = 33; }, DecodeError::kBadLength);
  with(
      "longer than 64", [](CanFdFrame& f) { f.len = 200; }, DecodeError::kBadLength);
  with(
      "short non-last fragment", [](CanFdFrame& f) { f.len = 48; }, DecodeError::kBadLength);
  with(
      "index beyond count", [](CanFdFrame& f) { f.data[2] = 0x53; }, DecodeError::kBadLength);
  with(
      "too many fragments", [](CanFdFrame& f) { f.data[2] = 0x0F; }, DecodeError::kBadLength);
  CanFdReassembler reassembler;
  for (const Case& c : cases) {
    std::optional<AnyMessage> done;
    EXPECT_EQ(reassembler.push(c.frame, 0, done), c.expected) << c.what;
    EXPECT_FALSE(done);
  }
  const auto& k = reassembler.counters();
  EXPECT_EQ(k.not_ours, 2u);
  EXPECT_EQ(k.bad_version, 1u);
  EXPECT_EQ(k.unknown_type, 2u);
  EXPECT_EQ(k.bad_length, 7u);
  EXPECT_EQ(reassembler.in_flight(), 0u);

  // Transfer-level inconsistencies: unit in the id differs from the payload's unit_id.
  {
    auto frames = encode(m);
    for (auto& f : frames)
      f.can_id ^= 1u << canid::kUnitShift;
    std::optional<AnyMessage> done;
    DecodeError last = DecodeError::kNone;
    for (const auto& f : frames)
      last = reassembler.push(f, 0, done);
    EXPECT_EQ(last, DecodeError::kOutOfRange);
    EXPECT_FALSE(done);
  }
  // Conflicting fragment counts for the same transfer.
  {
    MarkObservations other = m;
    other.trigger_seq += 1;
    auto frames = encode(other);
    std::optional<AnyMessage> done;
    EXPECT_EQ(reassembler.push(frames[0], 0, done), DecodeError::kNone);
    CanFdFrame f = frames[1];
    f.data[2] = 0x14;  // index 1 of 5 instead of 4
    EXPECT_EQ(reassembler.push(f, 0, done), DecodeError::kBadLength);
  }
}

TEST(MsgCanFd, RandomFramesNeverCrash) {
  std::mt19937_64 rng(18);
  CanFdReassembler reassembler;
  const auto valid = encode(test::random_observations(rng, 40));
  std::int64_t now = 0;
  constexpr int kTrials = 300000;
  for (int i = 0; i < kTrials; ++i) {
    CanFdFrame f;
    if (i % 3 == 0) {
      f = valid[rng() % valid.size()];  // mutate a valid frame
      f.data[rng() % 64] = static_cast<std::uint8_t>(rng());
      if (rng() % 4 == 0) f.len = static_cast<std::uint8_t>(rng());
    } else {
      // Random but mostly well-shaped frames, so that slots fill and transfers complete.
      const auto id = static_cast<std::uint8_t>(1 + rng() % 2);
      f.can_id = canid::make(canid::kLccNoc, id, static_cast<std::uint8_t>(rng() % 4), 0,
                             canid::message_version(static_cast<MessageId>(id)));
      f.len = 64;
      for (auto& b : f.data)
        b = static_cast<std::uint8_t>(rng());
      f.data[0] = 0;
      f.data[1] = static_cast<std::uint8_t>(rng() % 8);
      if (i % 3 == 2) f.can_id = static_cast<std::uint32_t>(rng());
    }
    std::optional<AnyMessage> done;
    reassembler.push(f, now += 1000, done);
  }
  const auto& c = reassembler.counters();
  EXPECT_EQ(c.frames, static_cast<std::uint64_t>(kTrials));
  EXPECT_LE(reassembler.in_flight(), CanFdReassembler::kSlots);
  const std::uint64_t rejected =
      c.not_ours + c.bad_version + c.bad_length + c.unknown_type + c.out_of_range + c.crc_errors;
  EXPECT_GT(rejected, 0u);
  EXPECT_GT(c.fragments_accepted, 0u);
}

TEST(MsgCanFd, LinuxFrameConversion) {
  std::mt19937_64 rng(19);
  const auto frames = encode(test::random_observations(rng, 23));
  for (const CanFdFrame& f : frames) {
    const canfd_frame lf = to_linux(f);
    EXPECT_TRUE(lf.can_id & CAN_EFF_FLAG);
    EXPECT_EQ(lf.can_id & CAN_EFF_MASK, f.can_id);
    EXPECT_EQ(lf.len, f.len);
    CanFdFrame back;
    ASSERT_TRUE(from_linux(lf, back));
    EXPECT_EQ(back.can_id, f.can_id);
    EXPECT_EQ(back.len, f.len);
    EXPECT_TRUE(std::equal(f.data, f.data + f.len, back.data));
  }
  canfd_frame standard{};
  standard.can_id = 0x123;
  CanFdFrame out;
  EXPECT_FALSE(from_linux(standard, out));
}

}  // namespace
}  // namespace storetrack::msg
