// Forward kinematics of joints and keypoints with analytic Jacobians (native kernel).
//
// Same math and conventions as mocapgraph/body/kinematics.py (the numpy reference):
//   G_0 = R_root, J_0 = t_root, G_c = G_p Exp(theta_c), J_c = J_p + G_p o_c(beta),
//   keypoint k = sum_c a_kc J_c + G_c l_kc(beta).
// Jacobian columns, P = 6 + 3 (J - 1) + S (J = 22 joints gives 6 + 63 + S):
//   [0:3]  root rotation, right perturbation R <- R Exp(w);
//   [3:6]  root translation in the root frame, t <- t + R v;
//   [6:6+3(J-1)]  the local axis-angle vectors theta_1..theta_{J-1} themselves;
//   [6+3(J-1):]   the shape vector beta.
// All arrays are row-major (C-contiguous) float64; positions in metres, world frame.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace mocapgraph {

// Borrowed, read-only view of a BodyTable (mocapgraph/body/table.py).
struct BodyTableView {
  std::size_t num_joints = 0;     // J; joint 0 is the root
  std::size_t num_keypoints = 0;  // K
  std::size_t shape_dim = 0;      // S
  const std::int64_t* parents = nullptr;  // (J,), parents[0] = -1, 0 <= parents[c] < c
  const double* offsets = nullptr;        // (J, 3)
  const double* d_offsets = nullptr;      // (J, 3, S)
  const double* weights = nullptr;        // (K, J)
  const double* markers = nullptr;        // (K, J, 3)
  const double* d_markers = nullptr;      // (K, J, 3, S)
};

// Where one frame's results go; any pointer may be null to skip that output.
struct FrameOutputs {
  double* joints = nullptr;       // (J, 3)
  double* keypoints = nullptr;    // (K, 3)
  double* rotations = nullptr;    // (J, 3, 3) world-aligned joint frames G_c
  double* d_joints = nullptr;     // (J, 3, P)
  double* d_keypoints = nullptr;  // (K, 3, P)
};

// Per-thread scratch memory of BodyKernel::pose_frame; create with BodyKernel::make_workspace.
struct FkWorkspace {
  std::vector<double> rot;        // (J, 9) G_c
  std::vector<double> pos;        // (J, 3) J_c
  std::vector<double> axis_map;   // (J, 9) G_c Jr(theta_c)
  std::vector<double> d_pos;      // (J, 3, S) shape derivative of J_c
  std::vector<double> sub_sum;    // (J, 3) subtree sums of a_kd J_d + G_d l_kd
  std::vector<double> sub_weight; // (J,)   subtree sums of a_kd
  std::vector<double> block;      // (J, 9) per-joint 3x3 Jacobian blocks of the current point
};

class BodyKernel {
 public:
  // Copies nothing from the table (the view must outlive the kernel); precomputes sparsity.
  // Throws std::invalid_argument if the parents are not a tree in topological order.
  explicit BodyKernel(const BodyTableView& table);

  std::size_t num_joints() const { return table_.num_joints; }
  std::size_t num_keypoints() const { return table_.num_keypoints; }
  std::size_t shape_dim() const { return table_.shape_dim; }
  std::size_t num_params() const { return 6 + 3 * (table_.num_joints - 1) + table_.shape_dim; }

  FkWorkspace make_workspace() const;

  // One frame: root (4, 4) world_T_root, pose (J-1, 3) local axis-angle (radians).
  void pose_frame(const double* root, const double* pose, const FrameOutputs& out,
                  FkWorkspace& ws) const;

  // T frames: root (T, 4, 4), pose (T, J-1, 3); outputs are the per-frame arrays stacked on a
  // leading T axis (null pointers skip that output).
  void pose_frames(std::size_t frames, const double* root, const double* pose,
                   const FrameOutputs& out) const;

 private:
  struct Contribution {
    std::uint32_t joint;
    double weight;     // a_kd
    bool has_marker;   // l_kd != 0
    bool has_dmarker;  // dl_kd/dbeta != 0
  };

  BodyTableView table_;
  // Joints whose weight, marker or marker derivative is nonzero: those of keypoint k are
  // contributions_[contribution_start_[k] : contribution_start_[k + 1]].
  std::vector<Contribution> contributions_;
  std::vector<std::size_t> contribution_start_;
  // Those joints and all their ancestors, in decreasing index order (children before parents),
  // i.e. the only joints whose rotation moves the keypoint; same indexing via closure_start_.
  std::vector<std::uint32_t> closure_;
  std::vector<std::size_t> closure_start_;
  // (K, J) 1 where joint c is in the closure of keypoint k.
  std::vector<std::uint8_t> closure_mask_;
  // (J, J) 1 where [d, c]: c is a strict ancestor of d other than the root.
  std::vector<std::uint8_t> ancestor_mask_;
  // (J,) 1 where d_offsets[c] has a nonzero entry.
  std::vector<std::uint8_t> has_doffset_;
};

}  // namespace mocapgraph
