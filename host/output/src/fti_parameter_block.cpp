#include "storetrack/output/fti_parameter_block.hpp"

#include <cerrno>

#include "storetrack/output/big_endian.hpp"

namespace storetrack::output {
namespace {
// Offsets of docs/fti-output.md, "FTI parameter block".
constexpr std::size_t kTaiOffset = 0;
constexpr std::size_t kSeqOffset = 8;
constexpr std::size_t kStoreIdOffset = 12;
constexpr std::size_t kCamerasOffset = 13;
constexpr std::size_t kMarksOffset = 14;
constexpr std::size_t kPylonMarksOffset = 15;
constexpr std::size_t kStatusOffset = 16;
constexpr std::size_t kVersionOffset = kFtiParameterBlockVersionOffset;
constexpr std::size_t kPoseOffset = 20;         // x y z yaw pitch roll
constexpr std::size_t kUncertaintyOffset = 44;  // u of the six above
constexpr std::size_t kCorrelationOffset = 68;  // 15 floats
constexpr std::size_t kBudgetOffset = 128;      // centroid intrinsic extrinsic sync process
constexpr std::size_t kBudgetCount = 5;
constexpr std::size_t kCoverageOffset = 148;
static_assert(kBudgetOffset + 4 * kBudgetCount == kCoverageOffset);
static_assert(kCoverageOffset + 4 == kFtiParameterBlockBytes);
}  // namespace

int encode_fti_parameter_block(const msg::FtiSample& s, std::span<std::uint8_t> out) {
  if (out.size() < kFtiParameterBlockBytes) return -ENOSPC;
  std::uint8_t* p = out.data();
  be::put_u64(p + kTaiOffset, static_cast<std::uint64_t>(s.exposure_mid_tai_ns));
  be::put_u32(p + kSeqOffset, s.trigger_seq);
  be::put_u8(p + kStoreIdOffset, s.store_id);
  be::put_u8(p + kCamerasOffset, s.cameras_used);
  be::put_u8(p + kMarksOffset, s.marks_used);
  be::put_u8(p + kPylonMarksOffset, s.pylon_marks_used);
  be::put_u16(p + kStatusOffset, s.status);
  be::put_u16(p + kVersionOffset, kFtiParameterBlockVersion);
  const float pose[6] = {s.x_m, s.y_m, s.z_m, s.yaw_rad, s.pitch_rad, s.roll_rad};
  const float u[6] = {s.u_x_m, s.u_y_m, s.u_z_m, s.u_yaw_rad, s.u_pitch_rad, s.u_roll_rad};
  for (int i = 0; i < 6; ++i) {
    be::put_f32(p + kPoseOffset + 4 * i, pose[i]);
    be::put_f32(p + kUncertaintyOffset + 4 * i, u[i]);
  }
  for (int i = 0; i < 15; ++i)
    be::put_f32(p + kCorrelationOffset + 4 * i, s.correlation[i]);
  const float budget[kBudgetCount] = {s.u_budget_centroid_m, s.u_budget_intrinsic_m,
                                      s.u_budget_extrinsic_m, s.u_budget_sync_m,
                                      s.u_budget_process_m};
  for (std::size_t i = 0; i < kBudgetCount; ++i)
    be::put_f32(p + kBudgetOffset + 4 * i, budget[i]);
  be::put_f32(p + kCoverageOffset, s.coverage_factor);
  return static_cast<int>(kFtiParameterBlockBytes);
}

int decode_fti_parameter_block(std::span<const std::uint8_t> in, msg::FtiSample& s) {
  // The version first: a block of another version (version 1 was 4 bytes shorter) is refused
  // as such, not as a short block.
  if (in.size() < kVersionOffset + 2) return -EINVAL;
  const std::uint8_t* p = in.data();
  if (be::get_u16(p + kVersionOffset) != kFtiParameterBlockVersion) return -EPROTO;
  if (in.size() < kFtiParameterBlockBytes) return -EINVAL;
  s.exposure_mid_tai_ns = static_cast<std::int64_t>(be::get_u64(p + kTaiOffset));
  s.trigger_seq = be::get_u32(p + kSeqOffset);
  s.store_id = p[kStoreIdOffset];
  s.cameras_used = p[kCamerasOffset];
  s.marks_used = p[kMarksOffset];
  s.pylon_marks_used = p[kPylonMarksOffset];
  s.status = be::get_u16(p + kStatusOffset);
  float* pose[6] = {&s.x_m, &s.y_m, &s.z_m, &s.yaw_rad, &s.pitch_rad, &s.roll_rad};
  float* u[6] = {&s.u_x_m, &s.u_y_m, &s.u_z_m, &s.u_yaw_rad, &s.u_pitch_rad, &s.u_roll_rad};
  for (int i = 0; i < 6; ++i) {
    *pose[i] = be::get_f32(p + kPoseOffset + 4 * i);
    *u[i] = be::get_f32(p + kUncertaintyOffset + 4 * i);
  }
  for (int i = 0; i < 15; ++i)
    s.correlation[i] = be::get_f32(p + kCorrelationOffset + 4 * i);
  float* budget[kBudgetCount] = {&s.u_budget_centroid_m, &s.u_budget_intrinsic_m,
                                 &s.u_budget_extrinsic_m, &s.u_budget_sync_m,
                                 &s.u_budget_process_m};
  for (std::size_t i = 0; i < kBudgetCount; ++i)
    *budget[i] = be::get_f32(p + kBudgetOffset + 4 * i);
  s.coverage_factor = be::get_f32(p + kCoverageOffset);
  return 0;
}

std::string fti_parameter_block_error(std::span<const std::uint8_t> in) {
  if (in.size() < kVersionOffset + 2)
    return "FTI parameter block of " + std::to_string(in.size()) +
           " bytes: too short to hold its version (offset 18)";
  const unsigned version = be::get_u16(in.data() + kVersionOffset);
  if (version != kFtiParameterBlockVersion)
    return "FTI parameter block version " + std::to_string(version) +
           ": this reader decodes only version " + std::to_string(kFtiParameterBlockVersion) +
           " (" + std::to_string(kFtiParameterBlockBytes) + " bytes, docs/fti-output.md)";
  if (in.size() < kFtiParameterBlockBytes)
    return "FTI parameter block version " + std::to_string(version) + " of " +
           std::to_string(in.size()) + " bytes: needs " + std::to_string(kFtiParameterBlockBytes);
  return {};
}

}  // namespace storetrack::output
