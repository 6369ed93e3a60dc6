// Joint covariance of the rig fit. The normal matrix is ordered (x, b): x = every camera's free
// intrinsics (padded to 13 each) and every non-reference extrinsic, b = the board poses. The
// board poses couple only to x, so [[A, B], [B^T, D]] with D block-diagonal (6 x 6 per board):
// the x-block of the full inverse is exactly (A - sum_f B_f D_f^-1 B_f^T)^-1 (Schur complement),
// at the cost of one inverse of x's size instead of the whole matrix's.
#include <string>

#include "rig_refinement.hpp"
#include "storetrack/calib/rig_calibration.hpp"
#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::calib {
namespace {

constexpr int kN = camera::kNumIntrinsics;

struct BoardBlocks {
  geometry::Mat6 D = geometry::Mat6::Zero();  ///< board-board
  Eigen::MatrixXd B;                          ///< x-board
};

/// One view's sums J^T J over its used points, by parameter block: z = the camera's padded
/// intrinsics, e = its extrinsic, b = the board pose (all perturbations left).
struct ViewBlocks {
  Eigen::Matrix<double, kN, kN> zz = Eigen::Matrix<double, kN, kN>::Zero();
  Eigen::Matrix<double, kN, 6> ze = Eigen::Matrix<double, kN, 6>::Zero();
  Eigen::Matrix<double, kN, 6> zb = Eigen::Matrix<double, kN, 6>::Zero();
  geometry::Mat6 ee = geometry::Mat6::Zero(), eb = geometry::Mat6::Zero(),
                 bb = geometry::Mat6::Zero();
};

ViewBlocks view_blocks(const RigView& view, const std::vector<char>& used,
                       const IntrinsicParameterMap& map, const Eigen::Matrix<double, kN, kN>& M,
                       const RigState& state) {
  const auto ci = static_cast<size_t>(view.camera);
  const camera::CameraModel model(map.intrinsics(state.z[ci].data()));
  const geometry::Transform T_c_r = pose_transform(state.T_c_r[ci]);
  const geometry::Transform T_r_b = pose_transform(state.T_r_b[static_cast<size_t>(view.board)]);
  geometry::Mat6 d_cb_d_cr, d_cb_d_rb;
  geometry::composition_jacobians(T_c_r, T_r_b, d_cb_d_cr, d_cb_d_rb);
  ViewBlocks v;
  for (size_t k = 0; k < view.view.points.size(); ++k) {
    if (!used[k]) continue;
    const Observation& o = *view.view.points[k];
    camera::ProjectionJacobians J;
    if (!model.project_world(T_c_r * T_r_b, o.p_board, &J)) continue;
    const double w = 1.0 / o.weighting_sigma_px();
    const Eigen::Matrix<double, 2, kN> Jz = w * J.d_intrinsics * M;
    const Eigen::Matrix<double, 2, 6> Je = w * J.d_pose * d_cb_d_cr;
    const Eigen::Matrix<double, 2, 6> Jb = w * J.d_pose * d_cb_d_rb;
    v.zz.noalias() += Jz.transpose() * Jz;
    v.ze.noalias() += Jz.transpose() * Je;
    v.zb.noalias() += Jz.transpose() * Jb;
    v.ee.noalias() += Je.transpose() * Je;
    v.eb.noalias() += Je.transpose() * Jb;
    v.bb.noalias() += Jb.transpose() * Jb;
  }
  return v;
}

}  // namespace

Eigen::MatrixXd rig_covariance(const std::vector<RigView>& views,
                               const std::vector<std::vector<char>>& used,
                               const std::vector<IntrinsicParameterMap>& maps,
                               const RigState& state, const std::vector<int>& frames,
                               double residual_variance) {
  const int boards = static_cast<int>(frames.size());
  const int cameras = static_cast<int>(maps.size());
  const int n = kN * cameras + 6 * (cameras - 1);
  const auto extrinsic_index = [&](int c) { return kN * cameras + 6 * (c - 1); };
  std::vector<Eigen::Matrix<double, kN, kN>> M(maps.size());  // padded free -> packed
  for (int c = 0; c < cameras; ++c) {
    M[static_cast<size_t>(c)].setZero();
    M[static_cast<size_t>(c)].leftCols(maps[static_cast<size_t>(c)].size()) =
        maps[static_cast<size_t>(c)].jacobian();
  }
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(n, n);
  std::vector<BoardBlocks> blocks(static_cast<size_t>(boards));
  for (BoardBlocks& b : blocks)
    b.B = Eigen::MatrixXd::Zero(n, 6);
  for (size_t i = 0; i < views.size(); ++i) {
    const int c = views[i].camera;
    const ViewBlocks v = view_blocks(views[i], used[i], maps[static_cast<size_t>(c)],
                                     M[static_cast<size_t>(c)], state);
    // Scatter once per view (fixed-size sums per point above, not n x n updates per point).
    BoardBlocks& board = blocks[static_cast<size_t>(views[i].board)];
    A.block<kN, kN>(kN * c, kN * c) += v.zz;
    board.B.block<kN, 6>(kN * c, 0) += v.zb;
    board.D += v.bb;
    if (c == 0) continue;
    const int e = extrinsic_index(c);
    A.block<kN, 6>(kN * c, e) += v.ze;
    A.block<6, kN>(e, kN * c) += v.ze.transpose();
    A.block<6, 6>(e, e) += v.ee;
    board.B.block<6, 6>(e, 0) += v.eb;
  }
  Eigen::MatrixXd S = A;
  for (int f = 0; f < boards; ++f) {
    BoardBlocks& b = blocks[static_cast<size_t>(f)];
    geometry::Mat6 D_inv;
    if (!uncertainty::inverse_spd<6>(b.D, D_inv))
      throw CalibrationError("frame " + std::to_string(frames[static_cast<size_t>(f)]) +
                             ": its board pose is not determined by its points");
    S.noalias() -= b.B * D_inv * b.B.transpose();
  }
  for (int c = 0; c < cameras; ++c)
    for (int j = maps[static_cast<size_t>(c)].size(); j < kN; ++j)
      S(kN * c + j, kN * c + j) = 1;  // padding: decoupled unit block, dropped below
  Eigen::MatrixXd S_inv;
  if (!uncertainty::inverse_spd<Eigen::Dynamic>(S, S_inv))
    throw CalibrationError(
        "the rig's normal matrix is singular: the views do not determine every camera's free "
        "intrinsics and extrinsics (fix parameters or add tilted, shared views)");
  // Map x (padded free intrinsics, extrinsics) to the result's layout (packed, extrinsics).
  Eigen::MatrixXd G = Eigen::MatrixXd::Zero(kRigBlockSize * cameras, n);
  for (int c = 0; c < cameras; ++c) {
    G.block<kN, kN>(kRigBlockSize * c, kN * c) = M[static_cast<size_t>(c)];
    if (c > 0) G.block<6, 6>(kRigBlockSize * c + kN, extrinsic_index(c)).setIdentity();
  }
  return residual_variance * G * S_inv * G.transpose();
}

}  // namespace storetrack::calib
