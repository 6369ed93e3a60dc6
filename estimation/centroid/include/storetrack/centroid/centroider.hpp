// On-board centroiding of retro-reflective marks (the heart of the camera unit).
//
// Pipeline per frame (docs/centroiding.md has the method, the noise model and the accuracy):
//   1. background: sparse-grid median + clipped mean per coarse tile (a few % of the pixels);
//   2. threshold: per-tile level (background + threshold), scanned 128 pixels at a time with
//      vector maxima, so the dark frame costs about as much as reading it once;
//   3. connected components (8-connected) over run-length rows, one pass, union-find on runs;
//   4. per component: background-subtracted moments, flux, peak, area, ellipse, flags;
//   5. refinement: Newton steps of the maximum-likelihood weighted centroid for a Gaussian
//      template under photon + read noise (Smith et al. 2010; Mortensen et al. 2010), started
//      from the threshold moments; fallback: iterative Gaussian-windowed centroid (SExtractor
//      XWIN_IMAGE, Bertin & Arnouts 1996). The standard deviation is propagated from the
//      per-pixel photon + read + quantisation variance through the estimating equation.
//
// The per-frame path works in place on the caller's buffer (an mmap'd V4L2 buffer): it does not
// copy the frame, allocate or throw. All scratch memory is sized in the constructor.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "storetrack/frame/frame_source.hpp"

namespace storetrack::centroid {

/// Blob quality bits; identical to msg::mark_flags (the wire bits of MarkObservation.flags).
namespace blob_flags {
inline constexpr std::uint8_t kSaturated = 1;  ///< a pixel reached the saturation level
inline constexpr std::uint8_t kBorder = 2;     ///< touches the image/ROI border or window clipped
inline constexpr std::uint8_t kMerged = 4;     ///< several separated maxima, or area too large
inline constexpr std::uint8_t kElongated = 8;  ///< second-moment axis ratio above the limit
}  // namespace blob_flags

struct CentroidConfig {
  // --- Detection --------------------------------------------------------------------------
  /// Detection level above the local background [DN of the frame's format]. <= 0: use
  /// threshold_sigma times the background noise of the noise model below.
  int threshold_dn = 0;
  double threshold_sigma = 6.0;
  int min_area_px = 3;    ///< smaller components (hot pixels, noise) are dropped
  int max_area_px = 600;  ///< larger components are flagged merged
  // --- Background -------------------------------------------------------------------------
  int background_tile_px = 128;       ///< tile edge; rounded up to a multiple of 128
  int background_row_step_px = 32;    ///< background samples: every n-th row of a tile,
  int background_column_step_px = 4;  ///< every n-th pixel of those rows
  // --- Noise model (EMVA 1288 linear camera), for thresholds and sigma_px ----------------------
  double read_noise_e = 12.0;   ///< temporal read noise [e-]
  double gain_e_per_dn = 20.0;  ///< electrons per DN of the frame's format
  double black_level_dn = 0.0;  ///< offset added by the ADC [DN]
  int saturation_dn = 0;        ///< 0: full scale 2^bits - 1
  // --- Refinement -------------------------------------------------------------------------
  bool refine = true;              ///< sub-pixel refinement; false: threshold moments only
  double window_sigma_px = 0.0;    ///< > 0: fixed window sigma; 0: matched to each blob
  int max_refine_iterations = 16;  ///< iterations of the windowed centroid
  double refine_tolerance_px = 1e-4;
  /// Maximum-likelihood weighting g / (v0 + k A g) (Gaussian template, photon + read noise),
  /// started from the threshold moments (fast start) or after the windowed centroid: reaches
  /// the Cramer-Rao bound when photon noise dominates the spot's core. Off: windowed only.
  bool photon_weighting = true;
  int photon_weighting_steps = 1;     ///< after the windowed centroid; fast start uses one more
  double window_radius_sigmas = 3.0;  ///< refinement patch half-size in window sigmas
  int max_window_half_px = 15;        ///< refinement patch is at most (2h+1)^2 pixels
  // --- Shape flags ------------------------------------------------------------------------
  double max_axis_ratio = 1.5;  ///< sqrt(major/minor second moment) above this: kElongated
  /// Secondary maximum taller than this fraction of the main peak (above background), at least
  /// 2 px away and separated by a dip below (1 - merge_dip_fraction) of its height: kMerged.
  double merge_peak_fraction = 0.25;
  double merge_dip_fraction = 0.2;
  // --- Capacity (all memory is sized from these in the constructor) ------------------------------
  int max_runs = 65536;       ///< run-length segments per frame; more: the frame is refused
  int max_candidates = 4096;  ///< connected components per frame; more are dropped, counted
  int max_rois = 64;          ///< regions of interest per call
};

/// Region of interest [x, x + width) x [y, y + height) in pixels; clipped to the frame.
struct Roi {
  int x = 0, y = 0, width = 0, height = 0;
};

/// One detected mark. Positions follow docs/conventions.md (centre of the top-left pixel is
/// (0, 0)); DN values are in the frame's own format, above the local background.
struct Blob {
  double x_px = 0, y_px = 0;
  double sigma_px = 0;      ///< standard uncertainty per axis (isotropic), noise model
  float peak_dn = 0;        ///< brightest pixel above background
  float flux_dn = 0;        ///< background-subtracted sum over the refinement patch
  float area_px = 0;        ///< pixels above the threshold
  float diameter_px = 0;    ///< equivalent diameter sqrt(4 area / pi)
  float axis_ratio = 1;     ///< sqrt(major / minor) of the intensity second moments
  std::uint8_t flags = 0;   ///< blob_flags (= msg::mark_flags)
  float background_dn = 0;  ///< local background level under the blob [DN]
};

/// Counters since construction, and the last frame's levels (for health and bench aids).
struct CentroidStats {
  std::uint64_t frames = 0;
  std::uint64_t frames_refused = 0;      ///< bad frame (-EINVAL) or run overflow (-EOVERFLOW)
  std::uint64_t run_overflows = 0;       ///< frames with more than max_runs runs
  std::uint64_t candidates_dropped = 0;  ///< components beyond max_candidates
  std::uint64_t blobs_too_small = 0;     ///< components below min_area_px
  std::uint64_t blobs_truncated = 0;     ///< blobs beyond the output span (faintest dropped)
  std::uint64_t fast_starts = 0;  ///< blobs refined by the ML step straight from threshold moments
  std::uint64_t refine_fallbacks = 0;  ///< windowed centroid failed: threshold moments used
  int last_candidates = 0;
  int last_runs = 0;
  /// Median over the tiles estimated (all of them for a full frame; in ROI mode those under
  /// the ROIs and their interpolation neighbours; unchanged when no ROI is left) of the level.
  float last_background_dn = 0;
  float last_noise_dn = 0;      ///< background noise of the noise model at that level
  float last_threshold_dn = 0;  ///< detection level above background at that level
};

class Centroider {
 public:
  /// Throws std::invalid_argument on an inconsistent configuration (not per frame).
  Centroider(const CentroidConfig& config, int max_width, int max_height);

  /// Detects and measures the marks of a whole frame. Returns the number of blobs written to
  /// `out` (the brightest ones if there are more, counted in stats().blobs_truncated), or
  /// -EINVAL (bad frame), -EOVERFLOW (more runs than max_runs). Never allocates or throws.
  int process(const frame::FrameView& frame, std::span<Blob> out);

  /// Same, searching only inside `rois` (clipped to the frame; they should not overlap, an
  /// overlapping mark is reported once per ROI). Blobs touching an ROI edge are kBorder.
  int process(const frame::FrameView& frame, std::span<const Roi> rois, std::span<Blob> out);

  const CentroidStats& stats() const { return stats_; }
  const CentroidConfig& config() const { return config_; }

 private:
  struct Run {
    std::int32_t y, x0, x1;  // x1 inclusive
  };
  struct Region {
    int x0, y0, x1, y1;  // half-open
    int run_end;         // one past this region's last run
  };
  struct Candidate {
    double sw, swx, swy, swxx, swyy, swxy;  // background-subtracted moments about (ref_x, ref_y)
    double sv, svx, svy, svxx, svyy;        // per-pixel variance moments (fallback sigma)
    int ref_x, ref_y;
    int xmin, xmax, ymin, ymax;
    int area;
    int peak, peak_x, peak_y;
    int saturated;
    int region;
    float background;
  };

  int process_regions(const frame::FrameView& frame, bool whole_frame, std::span<Blob> out);
  int check_frame(const frame::FrameView& frame) const;
  template <typename Pixel>
  void estimate_background(const frame::FrameView& frame, bool whole_frame);
  template <typename Pixel>
  void estimate_tile(const frame::FrameView& frame, int tx, int ty);
  void mark_region_tiles(const Region& region);
  template <typename Pixel>
  void prefetch_first_rows(const frame::FrameView& frame) const;
  template <typename Pixel>
  int scan_region(const frame::FrameView& frame, int region_index, bool prefetch);
  template <typename Pixel>
  void accumulate(const frame::FrameView& frame);
  template <typename Pixel>
  bool measure(const frame::FrameView& frame, int candidate_index, Blob& blob);
  template <typename Pixel>
  bool has_separate_maxima(const frame::FrameView& frame, const Candidate& c) const;
  template <typename Pixel>
  bool refine(const frame::FrameView& frame, int candidate_index, Blob& blob);
  bool photon_weighted_step(double sigma, float background, double amplitude, int steps, double& xc,
                            double& yc, double& var_x, double& var_y, double& flux);
  bool windowed_variance(double sigma, float background, double xc, double yc, double& var_x,
                         double& var_y, double& flux);
  int find(int run) const;
  void unite(int a, int b);
  float background_at(double x, double y) const;
  /// Noise model variance of a pixel reading value_dn [DN^2].
  double pixel_variance_dn2(double value_dn) const {
    const double above_black = value_dn - config_.black_level_dn;
    return (above_black > 0 ? above_black * variance_per_dn_ : 0.0) + variance_offset_dn2_;
  }

  CentroidConfig config_;
  int max_width_, max_height_;
  int tile_px_;
  int tiles_x_, tiles_y_;
  int frame_width_ = 0, frame_height_ = 0;  // of the current frame
  double variance_per_dn_ = 0, variance_offset_dn2_ = 0;
  int saturation_dn_ = 0;  // of the current frame
  int max_value_ = 0;      // 2^bits - 1 of the current frame
  std::vector<Run> runs_;
  mutable std::vector<std::int32_t> parent_;
  std::vector<std::int32_t> label_;
  int run_count_ = 0;
  bool run_overflow_ = false;
  std::vector<Region> regions_;
  int region_count_ = 0;
  std::vector<Candidate> candidates_;
  int candidate_count_ = 0;
  std::vector<std::int32_t> selected_;  // candidates measured this frame, raster order
  int selected_count_ = 0;
  std::vector<float> tile_background_;
  std::vector<std::int32_t> tile_threshold_;       // absolute: pixel > level is foreground
  std::vector<std::int32_t> row_threshold_;        // per 128-pixel chunk of the current tile row
  std::vector<std::int32_t> chunk_tile_;           // tile column of each 128-pixel chunk
  std::vector<std::uint16_t> samples_;             // one tile's background samples (Mono16)
  std::vector<float> sorted_tiles_;                // tile levels for the frame median
  std::vector<std::uint8_t> tile_wanted_;          // ROI mode: 1 for the tiles under the ROIs
  mutable std::vector<std::uint16_t> column_max_;  // merge check: 3-row maxima of a blob's box
  int patch_x0_ = 0, patch_y0_ = 0, patch_w_ = 0, patch_h_ = 0;
  std::vector<float> patch_;       // refinement patch, background-subtracted [DN]
  std::vector<float> patch_keep_;  // 1: pixel used, 0: it belongs to another mark's box
  std::vector<float> flat_dx_, flat_dy_, flat_g_;  // per patch pixel, for the ML step
  std::vector<float> wx_, wy_, dx_, dy_;           // window samples and offsets of the patch
  CentroidStats stats_;
};

}  // namespace storetrack::centroid
