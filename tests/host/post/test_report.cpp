// storetrack-post --report's data (host/post report_data) against the simulator's truth: the
// simulator's exposures through the host's processor with the TRUE rig stated perfect and the
// true surveys, so the residuals are centroid noise alone and their predicted spread is exact.
// - the per-camera windows of normalised residuals hold their chi-square band (0.95) at the
//   binomial rate (two-sided, alpha 0.025 per side, over all windows);
// - the rigid-body fit chi-square exceeds its 0.99 quantile no more often than the binomial
//   band allows (its weights include the body-mark survey's sigma, here with the true surveys:
//   chi2/dof 0.09 store, 0.008 pylon, so the check is one-sided in effect: a moved or
//   misidentified mark shows as too many exceedances);
// - a camera dropped over known exposures shows as not delivered at exactly those exposures.
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "report_data.hpp"
#include "report_files.hpp"
#include "scratch_files.hpp"
#include "sim_exposure.hpp"
#include "storetrack/pipeline/exposure_processor.hpp"

namespace storetrack::post {
namespace {

// The scenario's whole 0.55 s at 400 fps (220 exposures: captive, ejector stroke, free flight);
// 2.8 s here, one pass, so the sanitizer runs take the same form.
constexpr int kExposures = 220;
constexpr int kDroppedCamera = 2, kDropFirst = 40, kDropEnd = 70;  // exposures [40, 70)

struct ProcessedRun {
  std::vector<int> rig_camera_ids;
  std::vector<CameraResidualRow> residuals;
  std::vector<ExposureRow> exposures;
};

// The simulator's exposures processed; camera `drop` (its rig index) removed from the exposures
// in [drop_first, drop_end), as the aligner closes an exposure without it.
ProcessedRun process(int drop, int drop_first, int drop_end) {
  const sim::Simulator sim(sim::load_scenario(test::scenario_path("store_separation")), 261);
  const camera::RigCalibration rig = test::perfect_rig(sim);
  pipeline::ExposureProcessor processor(rig, sim.true_pylon(), sim.true_store(),
                                        pipeline::ProcessorConfig{});
  ProcessedRun run;
  for (const camera::CalibratedCamera& c : rig.cameras)
    run.rig_camera_ids.push_back(c.camera_id);
  for (int k = 0; k < std::min(kExposures, sim.num_exposures()); ++k) {
    test::SimExposure in = test::make_exposure(sim, k);
    if (k >= drop_first && k < drop_end) {
      const int id = run.rig_camera_ids[static_cast<std::size_t>(drop)];
      for (std::size_t c = 0; c < in.exposure.cameras.size(); ++c)
        if (in.exposure.cameras[c].camera_id == id) {
          in.exposure.cameras.erase(in.exposure.cameras.begin() + static_cast<std::ptrdiff_t>(c));
          in.ids.erase(in.ids.begin() + static_cast<std::ptrdiff_t>(c));
          break;
        }
      in.exposure.missing_camera_mask = 1u << drop;
    }
    const pipeline::ExposureResult r = processor.process(in.exposure, in.ids);
    for (const CameraResidualRow& row : camera_residual_rows(in.exposure, r, rig))
      run.residuals.push_back(row);
    run.exposures.push_back(exposure_row(in.exposure, r, true));
  }
  return run;
}

const ProcessedRun& clean_run() {
  static const ProcessedRun run = process(0, 0, 0);
  return run;
}

TEST(PostReport, ResidualWindowsHoldTheirChiSquareBandAtTheBinomialRate) {
  const std::vector<ResidualWindow> windows =
      residual_windows(clean_run().residuals, kResidualWindowExposures);
  const std::size_t cameras = clean_run().rig_camera_ids.size();
  const std::size_t exposures = clean_run().exposures.size();
  ASSERT_EQ(windows.size(), cameras * (exposures / kResidualWindowExposures));
  const WindowsInside all = windows_inside(windows);
  double rms2 = 0;
  for (const ResidualWindow& w : windows) {
    EXPECT_GT(w.residuals, 0);
    EXPECT_LT(w.band_low, 1.0);
    EXPECT_GT(w.band_high, 1.0);
    rms2 += w.rms_normalised * w.rms_normalised;
  }
  std::printf(
      "%lld of %lld windows inside their 0.95 band (acceptance %lld .. %lld); mean "
      "normalised square %.4f\n",
      static_cast<long long>(all.inside), static_cast<long long>(all.windows),
      static_cast<long long>(all.band_low), static_cast<long long>(all.band_high),
      rms2 / static_cast<double>(windows.size()));
  EXPECT_TRUE(all.acceptable()) << all.inside << " of " << all.windows << " inside, acceptance "
                                << all.band_low << " .. " << all.band_high;
}

TEST(PostReport, RigidFitChiSquareExceedsItsQuantileWithinTheBinomialBand) {
  for (const bool store : {true, false}) {
    const ChiSquareExceedance x = rigid_exceedance(clean_run().exposures, store);
    std::printf("%s: %lld of %lld fits above the 0.99 quantile (acceptance %lld .. %lld)\n",
                store ? "store" : "pylon", static_cast<long long>(x.above),
                static_cast<long long>(x.fits), static_cast<long long>(x.band_low),
                static_cast<long long>(x.band_high));
    double sum_ratio = 0;
    for (const ExposureRow& e : clean_run().exposures) {
      const int n = store ? e.store_marks : e.pylon_marks;
      if (n >= 3) sum_ratio += (store ? e.store_chi2 : e.pylon_chi2) / (3 * n - 6);
    }
    std::printf("  mean chi2/dof %.4f\n", sum_ratio / static_cast<double>(x.fits));
    EXPECT_GE(x.fits, static_cast<std::int64_t>(clean_run().exposures.size()) * 9 / 10)
        << (store ? "store" : "pylon");
    EXPECT_GE(x.above, x.band_low) << (store ? "store" : "pylon");
    EXPECT_LE(x.above, x.band_high) << (store ? "store" : "pylon");
  }
}

TEST(PostReport, ADroppedCameraShowsAtExactlyTheExposuresItMissed) {
  const ProcessedRun run = process(kDroppedCamera, kDropFirst, kDropEnd);
  const int dropped_id = run.rig_camera_ids[kDroppedCamera];
  std::set<std::uint32_t> missed;
  for (const CameraResidualRow& row : run.residuals) {
    if (row.delivered) continue;
    EXPECT_EQ(row.camera_id, dropped_id) << "seq " << row.trigger_seq;
    EXPECT_EQ(row.residuals, 0);
    missed.insert(row.trigger_seq);
  }
  const std::uint32_t seq0 = run.exposures.front().trigger_seq;
  std::set<std::uint32_t> expected;
  for (int k = kDropFirst; k < kDropEnd; ++k)
    expected.insert(seq0 + static_cast<std::uint32_t>(k));
  EXPECT_EQ(missed, expected);
  for (const ExposureRow& e : run.exposures) {
    const bool dropped = expected.count(e.trigger_seq) > 0;
    EXPECT_EQ(e.missing_camera_mask, dropped ? 1u << kDroppedCamera : 0u) << e.trigger_seq;
    EXPECT_EQ(e.cameras_delivered, static_cast<int>(run.rig_camera_ids.size()) - (dropped ? 1 : 0));
  }
}

TEST(PostReport, RefusesANonEmptyDirectoryByName) {
  namespace fs = std::filesystem;
  const fs::path dir = test::fresh_dir("st_post_report_dir");
  const std::string fresh = (dir / "new" / "report").string();
  prepare_report_dir(fresh);
  EXPECT_TRUE(fs::is_directory(fresh));
  prepare_report_dir(fresh);  // empty: accepted
  std::ofstream(fs::path(fresh) / "index.html") << "kept";
  try {
    prepare_report_dir(fresh);
    ADD_FAILURE() << "a non-empty directory was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind(fresh + ": not empty", 0), 0u) << e.what();
  }
  std::string kept;
  std::ifstream(fs::path(fresh) / "index.html") >> kept;
  EXPECT_EQ(kept, "kept");
  const std::string file = (fs::path(fresh) / "index.html").string();
  EXPECT_THROW(prepare_report_dir(file), std::runtime_error);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace storetrack::post
