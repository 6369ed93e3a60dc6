#include "storetrack/live/live_coverage.hpp"

#include <algorithm>

namespace storetrack::live {
namespace {

// z of (a - o) x (b - o): > 0 when o -> a -> b turns counter-clockwise.
double cross(const geometry::Vec2& o, const geometry::Vec2& a, const geometry::Vec2& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

bool inside_image(const camera::Intrinsics& in, const geometry::Vec2& px) {
  return px.x() >= -0.5 && px.y() >= -0.5 && px.x() <= in.width - 0.5 && px.y() <= in.height - 0.5;
}

// One half of the monotone chain over sorted points, appended to `hull`; `keep` points of the
// hull so far are never popped (the other half's).
void add_chain(const std::vector<geometry::Vec2>& sorted, std::size_t keep,
               std::vector<geometry::Vec2>& hull) {
  for (const geometry::Vec2& p : sorted) {
    while (hull.size() >= keep + 2 && cross(hull[hull.size() - 2], hull.back(), p) <= 0)
      hull.pop_back();
    hull.push_back(p);
  }
}

}  // namespace

std::vector<geometry::Vec2> convex_hull(std::vector<geometry::Vec2> points) {
  const auto less = [](const geometry::Vec2& a, const geometry::Vec2& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  };
  std::sort(points.begin(), points.end(), less);
  points.erase(std::unique(points.begin(), points.end()), points.end());
  if (points.size() < 3) return points;
  std::vector<geometry::Vec2> hull;
  add_chain(points, 0, hull);  // lower chain, left to right
  hull.pop_back();             // its last point starts the upper chain
  std::reverse(points.begin(), points.end());
  add_chain(points, hull.size(), hull);  // upper chain, right to left
  hull.pop_back();                       // back at the first point
  return hull;
}

std::vector<CoverageOutline> coverage_outlines(const camera::CalibratedCamera& camera,
                                               const geometry::Transform& T_w_p,
                                               const std::vector<geometry::Transform>& envelope_p,
                                               const survey::RigidBodySurvey& store) {
  const camera::Intrinsics& in = camera.model.intrinsics();
  std::vector<CoverageOutline> out(envelope_p.size());
  for (std::size_t k = 0; k < envelope_p.size(); ++k) {
    const geometry::Transform T_w_s = T_w_p * envelope_p[k];
    CoverageOutline& o = out[k];
    for (const survey::SurveyedMark& m : store.marks) {
      const auto px = camera::project_body_point(camera, T_w_s, m.p_body);
      o.leaves_image = o.leaves_image || !px || !inside_image(in, *px);
      if (px) o.points.push_back(*px);
    }
    o.hull = convex_hull(o.points);
  }
  return out;
}

}  // namespace storetrack::live
