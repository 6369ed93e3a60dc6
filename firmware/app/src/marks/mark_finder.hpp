// MarkFinder: where the marks of a frame are found. Today the centroider on the whole frame or
// on the search region an operator set (Modbus roi_*); a tracking mode (firmware/track, the
// predicted-window tracker) is a way of finding marks and belongs here, behind find().
// Fixed storage: find() neither allocates nor throws.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <span>
#include <string>

#include "storetrack/centroid/centroider.hpp"
#include "storetrack/frame/frame_source.hpp"
#include "storetrack/msg/messages.hpp"

namespace storetrack::unit {

/// The configured search region (roi_*): all zero for the whole frame; a width or height of 0
/// reaches to the frame's edge.
struct SearchRegion {
  int x = 0;
  int y = 0;
  int width = 0;
  int height = 0;
  bool whole_frame() const { return x <= 0 && y <= 0 && width <= 0 && height <= 0; }
};

class MarkFinder {
 public:
  /// The centroider for frames of this size. False with `error` when its configuration is
  /// refused.
  bool configure(const centroid::CentroidConfig& config, int width, int height, std::string& error);
  bool configured() const { return centroider_ != nullptr; }
  const centroid::CentroidConfig& config() const { return centroider_->config(); }
  /// A new detection threshold: a new centroider (allocates: maintenance mode only). False
  /// when refused; the old one goes on.
  bool set_threshold(int threshold_dn);

  /// The marks of `frame`: their count, or -errno when the frame is refused. Adds to `flags`
  /// what the message says of the search (kRoiMode, kMarksTruncated).
  int find(const frame::FrameView& frame, const SearchRegion& region, std::uint16_t& flags);
  /// The marks of the last find().
  std::span<const centroid::Blob> marks(int count) const {
    return {blobs_.data(), static_cast<std::size_t>(count)};
  }
  /// How long the last find() took, in microseconds.
  double last_time_us() const { return last_time_us_; }
  /// The "centroid" block of the stats (when configured).
  void add_stats(nlohmann::json& stats) const;

 private:
  std::unique_ptr<centroid::Centroider> centroider_;
  int width_ = 0;
  int height_ = 0;
  std::array<centroid::Blob, msg::kMaxMarks> blobs_{};
  std::uint64_t truncated_seen_ = 0;
  double last_time_us_ = 0;
};

}  // namespace storetrack::unit
