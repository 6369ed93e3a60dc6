// Bench aid: the current frame with the detected marks overlaid, and per-mark focus/exposure
// figures (peak, FWHM, SNR) for aiming and focusing cameras in the pod.
#pragma once

#include <cstdio>
#include <span>
#include <string>
#include <vector>

#include "storetrack/centroid/centroider.hpp"
#include "storetrack/frame/frame_source.hpp"

namespace storetrack::unit {

struct MarkFigures {
  double peak_dn = 0;  ///< brightest pixel above background
  double fwhm_px = 0;  ///< 2 sqrt(A_half / pi): A_half = pixels at or above half the peak
  double snr = 0;      ///< flux / noise, CCD equation with the centroider's noise model
};

/// Measures one blob on the frame (pure; no allocation).
MarkFigures measure_mark(const frame::FrameView& frame, const centroid::Blob& blob,
                         const centroid::CentroidConfig& noise);

/// Writes the overlay: RGB PNG when built with libpng (returns the path written), else a PGM
/// of the frame plus the overlay drawn in white/black. `path_stem` gets ".png" or ".pgm".
/// Returns the written path, or "" on failure (error in *error).
std::string write_overlay(const std::string& path_stem, const frame::FrameView& frame,
                          std::span<const centroid::Blob> blobs, std::string* error);

/// Prints the per-mark table (index, x, y, sigma, peak, FWHM, SNR, flags).
void print_mark_table(std::FILE* out, const frame::FrameView& frame,
                      std::span<const centroid::Blob> blobs, const centroid::CentroidConfig& noise);

/// Flag letters: S saturated, B border, M merged, E elongated ("-" for none).
std::string flag_letters(std::uint8_t flags);

}  // namespace storetrack::unit
