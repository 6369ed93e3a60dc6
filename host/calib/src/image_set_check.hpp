// The checks every detector (chessboard, ChArUco, dot grid) makes on one camera's images before
// looking for a board in them: readable, and the size of the first readable image.
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace storetrack::calib {

inline std::string size_text(const cv::Size& s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

class ImageSetCheck {
 public:
  /// Why `gray` (as cv::imread returned it) cannot be used, or empty; the first readable image
  /// fixes the set's size.
  std::string reason(const cv::Mat& gray) {
    if (gray.empty()) return "unreadable (missing file or not an image OpenCV decodes)";
    if (size_.empty()) size_ = gray.size();
    if (gray.size() != size_)
      return "image size " + size_text(gray.size()) + " differs from the first image's " +
             size_text(size_);
    return {};
  }
  /// The set's image size (empty while no image was readable).
  const cv::Size& size() const { return size_; }

 private:
  cv::Size size_;
};

}  // namespace storetrack::calib
