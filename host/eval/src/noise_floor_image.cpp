// Noise floor, seed 002's stereophotogrammetry assessment (docs/evaluation.md): image-coordinate
// error per camera, stereo angle per camera pair at each mark, reconstruction error of the
// surveyed distances in %.
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <utility>

#include "noise_floor_parts.hpp"

namespace storetrack::eval {

using geometry::Vec2;
using geometry::Vec3;

namespace {

/// Mean and sum of squared deviations of `values`.
std::pair<double, double> mean_ss(const std::vector<double>& values) {
  const double n = static_cast<double>(values.size());
  double mean = 0, ss = 0;
  for (double v : values)
    mean += v / n;
  for (double v : values)
    ss += (v - mean) * (v - mean);
  return {mean, ss};
}

/// One camera's accumulation over marks.
struct CameraAcc {
  CameraImageNoise out;
  std::array<double, 2> residual2 = {0, 0}, sd_sum = {0, 0}, chi = {0, 0};
  double sigma2 = 0;
  std::int64_t dof = 0, with_pixel = 0;
};

}  // namespace

void evaluate_image_coordinates(const MarksRecording& record, const EvaluatedSamples& marks,
                                NoiseFloorResult& r) {
  if (!record.has_observations) {
    std::string missing;
    for (const std::string& c : record.missing_observation_columns)
      missing += (missing.empty() ? "" : ", ") + c;
    r.image_coordinates_note = record.path + ": no image coordinates (missing column(s) " +
                               missing + "): image-coordinate error and stereo angles left out";
    return;
  }
  std::map<int, CameraAcc> cams;
  for (const std::vector<const MarkSample*>& samples : marks) {
    // This mark's centroid series per camera.
    std::map<int, std::array<std::vector<double>, 2>> pixels;
    std::map<int, double> sigma2;
    for (const MarkSample* s : samples)
      for (const MarkObservationSample& o : s->observations) {
        CameraAcc& c = cams[o.camera_id];
        ++c.out.observations;
        if (!o.pixel_px.allFinite() || !o.residual_px.allFinite()) {
          ++c.out.without_pixel;
          continue;
        }
        ++c.with_pixel;
        for (int a = 0; a < 2; ++a) {
          c.residual2[static_cast<size_t>(a)] += o.residual_px(a) * o.residual_px(a);
          pixels[o.camera_id][static_cast<size_t>(a)].push_back(o.pixel_px(a));
        }
        c.sigma2 += o.sigma_px * o.sigma_px;
        sigma2[o.camera_id] += o.sigma_px * o.sigma_px;
      }
    for (const auto& [camera_id, uv] : pixels) {
      const auto n = static_cast<std::int64_t>(uv[0].size());
      if (n < 3) continue;
      CameraAcc& c = cams[camera_id];
      ++c.out.marks;
      c.dof += n - 1;
      const double sigma2_mean = sigma2[camera_id] / static_cast<double>(n);
      for (int a = 0; a < 2; ++a) {
        const double ss = mean_ss(uv[static_cast<size_t>(a)]).second;
        c.sd_sum[static_cast<size_t>(a)] += std::sqrt(ss / static_cast<double>(n - 1));
        c.chi[static_cast<size_t>(a)] += ss / sigma2_mean;
      }
    }
  }
  for (auto& [camera_id, c] : cams) {
    c.out.camera_id = camera_id;
    c.out.pooled_dof = c.dof;
    const double n = static_cast<double>(std::max<std::int64_t>(c.with_pixel, 1));
    const ChiInterval interval =
        c.dof > 0 ? ratio_interval(c.dof, r.options.agreement_level) : ChiInterval{};
    for (int a = 0; a < 2; ++a) {
      ImageAxisNoise& x = c.out.axis[static_cast<size_t>(a)];
      x.residual_rms_px = std::sqrt(c.residual2[static_cast<size_t>(a)] / n);
      x.sigma_rms_px = std::sqrt(c.sigma2 / n);
      if (c.dof == 0) continue;
      x.temporal_sd_mean_px = c.sd_sum[static_cast<size_t>(a)] / c.out.marks;
      x.pooled_ratio = std::sqrt(c.chi[static_cast<size_t>(a)] / static_cast<double>(c.dof));
      x.pooled_low = interval.low;
      x.pooled_high = interval.high;
      x.agrees = x.pooled_ratio >= interval.low && x.pooled_ratio <= interval.high;
    }
    r.cameras.push_back(c.out);
  }
}

void evaluate_stereo_angles(const EvaluatedSamples& marks, const camera::RigCalibration& rig,
                            NoiseFloorResult& r) {
  const Vec3 towards_rig = -r.axes.axis[2];
  for (const std::vector<const MarkSample*>& samples : marks) {
    std::set<int> cameras;
    Vec3 mean = Vec3::Zero();
    for (const MarkSample* s : samples) {
      mean += s->p_w / static_cast<double>(samples.size());
      for (const MarkObservationSample& o : s->observations)
        cameras.insert(o.camera_id);
    }
    const std::vector<int> ids(cameras.begin(), cameras.end());
    for (size_t i = 0; i < ids.size(); ++i)
      for (size_t j = i + 1; j < ids.size(); ++j) {
        const Vec3 ray_a = camera_centre_w(*rig.find(ids[i])) - mean;
        const Vec3 ray_b = camera_centre_w(*rig.find(ids[j])) - mean;
        StereoAngle a;
        a.mark_id = samples.front()->mark_id;
        a.camera_a = ids[i];
        a.camera_b = ids[j];
        a.stereo_angle_rad = std::atan2(ray_a.cross(ray_b).norm(), ray_a.dot(ray_b));
        a.theta_a_rad = std::atan2(ray_a.cross(towards_rig).norm(), ray_a.dot(towards_rig));
        a.theta_b_rad = std::atan2(ray_b.cross(towards_rig).norm(), ray_b.dot(towards_rig));
        a.error_rad = a.theta_a_rad - a.theta_b_rad;
        r.stereo_angles.push_back(a);
      }
  }
}

void evaluate_distances(const EvaluatedSamples& marks, const survey::RigidBodySurvey& reference,
                        NoiseFloorResult& r) {
  for (size_t i = 0; i < marks.size(); ++i)
    for (size_t j = i + 1; j < marks.size(); ++j) {
      std::map<std::uint32_t, Vec3> a;
      for (const MarkSample* s : marks[i])
        a.emplace(s->trigger_seq, s->p_w);
      std::vector<double> d;
      Vec3 mean_a = Vec3::Zero(), mean_b = Vec3::Zero();
      for (const MarkSample* s : marks[j]) {
        const auto it = a.find(s->trigger_seq);
        if (it == a.end()) continue;
        d.push_back((it->second - s->p_w).norm());
        mean_a += it->second;
        mean_b += s->p_w;
      }
      if (d.size() < 3) continue;
      const double n = static_cast<double>(d.size());
      const survey::SurveyedMark& sa = *reference.find(marks[i].front()->mark_id);
      const survey::SurveyedMark& sb = *reference.find(marks[j].front()->mark_id);
      DistanceError e;
      e.id_a = sa.id;
      e.id_b = sb.id;
      e.samples = static_cast<int>(d.size());
      e.reference_m = (sa.p_body - sb.p_body).norm();
      e.measured_m = ((mean_a - mean_b) / n).norm();
      e.temporal_sd_m = std::sqrt(mean_ss(d).second / (n - 1));
      // The survey's isotropic per-axis sigma of each mark, along the pair's direction.
      e.u_measured_m = std::sqrt(e.temporal_sd_m * e.temporal_sd_m / n + sa.sigma_m * sa.sigma_m +
                                 sb.sigma_m * sb.sigma_m);
      e.error_percent = (e.measured_m - e.reference_m) / e.reference_m * 100;
      e.u_error_percent = e.u_measured_m / e.reference_m * 100;
      r.distances.push_back(e);
    }
}

}  // namespace storetrack::eval
