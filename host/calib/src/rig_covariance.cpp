// Joint covariance of the rig fit. The normal matrix is ordered (x, b): x = every camera's free
// intrinsics (padded to 13 each), every non-reference extrinsic and the board deflection (2,
// padding when not fitted), b = the board poses. The
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
  // w = the board deflection (c_x, c_y)
  Eigen::Matrix<double, kN, 2> zw = Eigen::Matrix<double, kN, 2>::Zero();
  Eigen::Matrix<double, 6, 2> ew = Eigen::Matrix<double, 6, 2>::Zero(),
                              bw = Eigen::Matrix<double, 6, 2>::Zero();
  Eigen::Matrix2d ww = Eigen::Matrix2d::Zero();
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
    if (!model.project_world(T_c_r * T_r_b, state.warp.apply(o.p_board), &J)) continue;
    const double w = 1.0 / o.weighting_sigma_px();
    // Coefficient-wise products throughout: Eigen's general product (blocking, packing) on
    // these 2-deep ones costs more than the arithmetic (docs/performance.md, issue 28).
    const Eigen::Matrix<double, 2, kN> Jz = w * J.d_intrinsics.lazyProduct(M);
    const Eigen::Matrix<double, 2, 6> Je = w * J.d_pose * d_cb_d_cr;
    const Eigen::Matrix<double, 2, 6> Jb = w * J.d_pose * d_cb_d_rb;
    const Eigen::Matrix2d Jw = w * J.d_point_world.col(2) * state.warp.basis(o.p_board).transpose();
    v.zw.noalias() += Jz.transpose().lazyProduct(Jw);
    v.ew.noalias() += Je.transpose() * Jw;
    v.bw.noalias() += Jb.transpose() * Jw;
    v.ww.noalias() += Jw.transpose() * Jw;
    v.zz.noalias() += Jz.transpose().lazyProduct(Jz);
    v.ze.noalias() += Jz.transpose().lazyProduct(Je);
    v.zb.noalias() += Jz.transpose().lazyProduct(Jb);
    v.ee.noalias() += Je.transpose() * Je;
    v.eb.noalias() += Je.transpose() * Jb;
    v.bb.noalias() += Jb.transpose() * Jb;
  }
  return v;
}

}  // namespace

RigCovariance rig_covariance(const std::vector<RigView>& views,
                             const std::vector<std::vector<char>>& used,
                             const std::vector<IntrinsicParameterMap>& maps, const RigState& state,
                             const std::vector<int>& frames, double residual_variance) {
  const int boards = static_cast<int>(frames.size());
  const int cameras = static_cast<int>(maps.size());
  const int warp = kN * cameras + 6 * (cameras - 1);  // index of c_x in x
  const int n = warp + 2;
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
    A.block<kN, 2>(kN * c, warp) += v.zw;
    A.block<2, kN>(warp, kN * c) += v.zw.transpose();
    A.block<2, 2>(warp, warp) += v.ww;
    board.B.block<2, 6>(warp, 0) += v.bw.transpose();
    if (c == 0) continue;
    const int e = extrinsic_index(c);
    A.block<kN, 6>(kN * c, e) += v.ze;
    A.block<6, kN>(e, kN * c) += v.ze.transpose();
    A.block<6, 6>(e, e) += v.ee;
    board.B.block<6, 6>(e, 0) += v.eb;
    A.block<6, 2>(e, warp) += v.ew;
    A.block<2, 6>(warp, e) += v.ew.transpose();
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
  std::vector<int> padding;
  for (int c = 0; c < cameras; ++c)
    for (int j = maps[static_cast<size_t>(c)].size(); j < kN; ++j)
      padding.push_back(kN * c + j);
  if (!state.warp.fitted) padding.insert(padding.end(), {warp, warp + 1});
  for (int j : padding) {  // padding: decoupled unit block, dropped below
    S.row(j).setZero();
    S.col(j).setZero();
    S(j, j) = 1;
  }
  Eigen::MatrixXd S_inv;
  if (!uncertainty::inverse_spd<Eigen::Dynamic>(S, S_inv))
    throw CalibrationError(
        "the rig's normal matrix is singular: the views do not determine every camera's free "
        "intrinsics and extrinsics" +
        std::string(state.warp.fitted ? " and the board deflection" : "") +
        " (fix parameters or add tilted, shared views)");
  for (int j : padding) {
    S_inv.row(j).setZero();
    S_inv.col(j).setZero();
  }
  // Map x (padded free intrinsics, extrinsics) to the result's layout (packed, extrinsics).
  Eigen::MatrixXd G = Eigen::MatrixXd::Zero(kRigBlockSize * cameras, n);
  for (int c = 0; c < cameras; ++c) {
    G.block<kN, kN>(kRigBlockSize * c, kN * c) = M[static_cast<size_t>(c)];
    if (c > 0) G.block<6, 6>(kRigBlockSize * c + kN, extrinsic_index(c)).setIdentity();
  }
  RigCovariance out;
  out.joint = residual_variance * G * S_inv * G.transpose();
  out.warp = residual_variance * S_inv.block<2, 2>(warp, warp);
  return out;
}

}  // namespace storetrack::calib
