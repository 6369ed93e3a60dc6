#include "intrinsic_covariance.hpp"

#include <string>
#include <vector>

#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::calib {
namespace {

// The global parameters: the packed intrinsics, then the board deflection (c_x, c_y).
constexpr int kIntrinsics = camera::kNumIntrinsics;
constexpr int kN = kIntrinsics + 2;
using MatN = Eigen::Matrix<double, kN, kN>;
using MatN6 = Eigen::Matrix<double, kN, 6>;

struct ViewBlocks {
  geometry::Mat6 D = geometry::Mat6::Zero();  ///< pose-pose
  MatN6 B = MatN6::Zero();                    ///< intrinsics-pose
  geometry::Mat6 D_inv;
};

/// weight * d pixel / d(free intrinsics padded to kIntrinsics, deflection (c_x, c_y)) of one
/// point: the intrinsics through the map's non-zero entries, the deflection's columns zero when
/// it is not fitted.
Eigen::Matrix<double, 2, kN> free_jacobian(const IntrinsicParameterMap& map,
                                           const camera::ProjectionJacobians& J,
                                           const BoardWarp& warp, const geometry::Vec3& p_board,
                                           double weight) {
  Eigen::Matrix<double, 2, kIntrinsics, Eigen::RowMajor> chained;
  map.chain_jacobian(J.d_intrinsics, weight, chained.data());
  Eigen::Matrix<double, 2, kN> Jz = Eigen::Matrix<double, 2, kN>::Zero();
  Jz.leftCols(map.size()) =
      Eigen::Map<const Eigen::Matrix<double, 2, Eigen::Dynamic, Eigen::RowMajor>>(chained.data(), 2,
                                                                                  map.size());
  if (warp.fitted)
    Jz.rightCols<2>() = weight * J.d_point_world.col(2) * warp.basis(p_board).transpose();
  return Jz;
}

}  // namespace

FitCovariance fit_covariance(const std::vector<BoardView>& views,
                             const std::vector<std::vector<char>>& used,
                             const IntrinsicParameterMap& map, const RefinementState& state,
                             double residual_variance) {
  const int p = map.size();
  const camera::CameraModel model(map.intrinsics(state.z.data()));
  // Free intrinsics padded to the fixed size kIntrinsics (padding columns of M are zero, so the
  // padding rows/columns of A and B stay zero), then the deflection's two columns (zero when it
  // is not fitted): fixed-size products throughout (quicker to compile than mixed dynamic ones)
  // and the tree's fixed-size SPD inverse applies.
  MatN M = MatN::Zero();
  M.topLeftCorner(kIntrinsics, p) = map.jacobian();
  const bool warp = state.warp.fitted;
  if (warp) M.bottomRightCorner<2, 2>().setIdentity();
  MatN A = MatN::Zero();
  std::vector<ViewBlocks> blocks(views.size());
  for (size_t i = 0; i < views.size(); ++i) {
    const geometry::Transform T_c_b = pose_transform(state.poses[i]);
    for (size_t k = 0; k < views[i].points.size(); ++k) {
      if (!used[i][k]) continue;
      const Observation& o = *views[i].points[k];
      camera::ProjectionJacobians J;
      if (!model.project_world(T_c_b, state.warp.apply(o.p_board), &J)) continue;
      const double w = 1.0 / o.weighting_sigma_px();
      const Eigen::Matrix<double, 2, kN> Jz = free_jacobian(map, J, state.warp, o.p_board, w);
      const Eigen::Matrix<double, 2, 6> Jp = w * J.d_pose;
      // Coefficient-wise products: Eigen's general product (blocking, packing) on these 2-deep
      // ones took most of the covariance's time (docs/performance.md, issue 28's speed item).
      A.noalias() += Jz.transpose().lazyProduct(Jz);
      blocks[i].B.noalias() += Jz.transpose().lazyProduct(Jp);
      blocks[i].D.noalias() += Jp.transpose().lazyProduct(Jp);
    }
  }
  MatN S = A;
  for (size_t i = 0; i < views.size(); ++i) {
    if (!uncertainty::inverse_spd<6>(blocks[i].D, blocks[i].D_inv))
      throw CalibrationError("view " + std::to_string(views[i].frame) +
                             ": its board pose is not determined by its points");
    S.noalias() -= blocks[i].B * blocks[i].D_inv * blocks[i].B.transpose();
  }
  std::vector<int> padding;
  for (int j = p; j < kIntrinsics; ++j)
    padding.push_back(j);
  if (!warp) padding.insert(padding.end(), {kIntrinsics, kIntrinsics + 1});
  for (int j : padding)
    S(j, j) = 1;  // padding: decoupled unit block, dropped below
  MatN S_inv;
  if (!uncertainty::inverse_spd<kN>(S, S_inv))
    throw CalibrationError(
        std::string("the normal matrix is singular: the views do not determine the free "
                    "intrinsics") +
        (warp ? " and the board deflection" : "") + " (fix parameters, add tilted views" +
        (warp ? " or set --board-deflection off)" : ")"));
  for (int j : padding) {
    S_inv.row(j).setZero();
    S_inv.col(j).setZero();
  }
  const MatN C_z = residual_variance * S_inv;
  FitCovariance out;
  const MatN C_global = M * C_z * M.transpose();
  out.intrinsics = C_global.topLeftCorner<kIntrinsics, kIntrinsics>();
  out.warp = C_global.bottomRightCorner<2, 2>();
  for (const ViewBlocks& b : blocks) {
    const Eigen::Matrix<double, kN, 6> SB = S_inv * b.B * b.D_inv;
    out.poses.push_back(residual_variance * (b.D_inv + b.D_inv * b.B.transpose() * SB));
  }
  return out;
}

}  // namespace storetrack::calib
