#include "marks/mark_finder.hpp"

#include <exception>
#include <nlohmann/json.hpp>

namespace storetrack::unit {

bool MarkFinder::configure(const centroid::CentroidConfig& config, int width, int height,
                           std::string& error) {
  width_ = width;
  height_ = height;
  try {
    centroider_ = std::make_unique<centroid::Centroider>(config, width, height);
  } catch (const std::exception& e) {
    error = std::string("centroid configuration: ") + e.what();
    return false;
  }
  return true;
}

bool MarkFinder::set_threshold(int threshold_dn) {
  centroid::CentroidConfig cc = centroider_->config();
  cc.threshold_dn = threshold_dn;
  try {
    centroider_ = std::make_unique<centroid::Centroider>(cc, width_, height_);
  } catch (const std::exception&) {
    return false;
  }
  return true;
}

int MarkFinder::find(const frame::FrameView& frame, const SearchRegion& region,
                     std::uint16_t& flags) {
  centroid::Roi roi[1];
  const bool use_roi = !region.whole_frame();
  if (use_roi) {
    roi[0].x = region.x;
    roi[0].y = region.y;
    roi[0].width = region.width > 0 ? region.width : frame.width - region.x;
    roi[0].height = region.height > 0 ? region.height : frame.height - region.y;
    flags |= msg::exposure_flags::kRoiMode;
  }
  const time::MonotonicNs t0 = time::monotonic_now_ns();
  const int n = use_roi
                    ? centroider_->process(frame, std::span<const centroid::Roi>(roi, 1), blobs_)
                    : centroider_->process(frame, blobs_);
  const time::MonotonicNs t1 = time::monotonic_now_ns();
  last_time_us_ = static_cast<double>(t1 - t0) / 1000.0;
  if (n < 0) return n;
  const std::uint64_t truncated = centroider_->stats().blobs_truncated;
  if (truncated != truncated_seen_) {
    flags |= msg::exposure_flags::kMarksTruncated;
    truncated_seen_ = truncated;
  }
  return n;
}

void MarkFinder::add_stats(nlohmann::json& stats) const {
  if (!centroider_) return;
  const centroid::CentroidStats& cs = centroider_->stats();
  stats["centroid"] = {{"frames", cs.frames},
                       {"frames_refused", cs.frames_refused},
                       {"blobs_truncated", cs.blobs_truncated},
                       {"blobs_too_small", cs.blobs_too_small},
                       {"last_background_dn", cs.last_background_dn},
                       {"last_threshold_dn", cs.last_threshold_dn}};
}

}  // namespace storetrack::unit
