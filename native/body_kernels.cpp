#include "body_kernels.h"
#include "so3.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

namespace mocapgraph {
namespace {

// y = A x for a 3x3 row-major A.
inline void mat_vec(const double* A, const double* x, double* y) {
  y[0] = A[0] * x[0] + A[1] * x[1] + A[2] * x[2];
  y[1] = A[3] * x[0] + A[4] * x[1] + A[5] * x[2];
  y[2] = A[6] * x[0] + A[7] * x[1] + A[8] * x[2];
}

// M = -[v]x A: the change of a point at lever v when its frame turns by the world axis A delta.
inline void neg_skew_mul(const double* v, const double* A, double* M) {
  for (int j = 0; j < 3; ++j) {
    const double c0 = A[j], c1 = A[3 + j], c2 = A[6 + j];  // column j of A
    M[j] = v[2] * c1 - v[1] * c2;
    M[3 + j] = v[0] * c2 - v[2] * c0;
    M[6 + j] = v[1] * c0 - v[0] * c1;
  }
}

// out (3, S) += G (3, 3) D (3, S) with row stride `out_stride` for out.
inline void add_rot_times_shape(const double* G, const double* D, std::size_t S, double* out,
                                std::size_t out_stride) {
  for (int i = 0; i < 3; ++i) {
    const double g0 = G[3 * i], g1 = G[3 * i + 1], g2 = G[3 * i + 2];
    double* o = out + i * out_stride;
    for (std::size_t s = 0; s < S; ++s) o[s] += g0 * D[s] + g1 * D[S + s] + g2 * D[2 * S + s];
  }
}

// True if some p[i] is neither +0 nor -0 (NaN counts as nonzero).
inline bool any_nonzero(const double* p, std::size_t n) {
  // Integer test on the bits without early exit: the sparsity scan runs on every call over
  // K x J x 3S mostly-zero entries, and this form vectorises where a double compare does not.
  std::uint64_t acc = 0;
  for (std::size_t i = 0; i < n; ++i) {
    std::uint64_t bits;
    std::memcpy(&bits, p + i, sizeof bits);
    acc |= bits << 1;  // drops the sign bit
  }
  return acc != 0;
}

// Row i (x, y or z) of a point's root and joint-rotation columns: blk[0:9] is the root-rotation
// block, blk[9c:9c+9] joint c's block (used where moves[c]), translation = scale * R0.
inline void write_pose_columns(double* row, int i, const double* blk, const double* R0, double scale,
                               const std::uint8_t* moves, std::size_t J) {
  for (int k = 0; k < 3; ++k) {
    row[k] = blk[3 * i + k];
    row[3 + k] = scale * R0[3 * i + k];
  }
  for (std::size_t c = 1; c < J; ++c) {
    double* r = row + 6 + 3 * (c - 1);
    for (int k = 0; k < 3; ++k) r[k] = moves[c] ? blk[9 * c + 3 * i + k] : 0.0;
  }
}

}  // namespace

BodyKernel::BodyKernel(const BodyTableView& table) : table_(table) {
  const std::size_t J = table.num_joints, K = table.num_keypoints, S = table.shape_dim;
  if (J == 0) throw std::invalid_argument("parents: the body needs at least the root joint");
  if (table.parents[0] != -1) throw std::invalid_argument("parents: parents[0] must be -1 (root)");
  for (std::size_t c = 1; c < J; ++c) {
    const std::int64_t p = table.parents[c];
    // Parents before children lets one forward sweep pose the whole tree.
    if (p < 0 || static_cast<std::size_t>(p) >= c)
      throw std::invalid_argument("parents: parents[" + std::to_string(c) +
                                  "] must be in [0, " + std::to_string(c) + ")");
  }

  ancestor_mask_.assign(J * J, 0);
  for (std::size_t d = 0; d < J; ++d) {
    for (std::int64_t c = table.parents[d]; c > 0; c = table.parents[c]) ancestor_mask_[d * J + c] = 1;
  }
  has_doffset_.assign(J, 0);
  for (std::size_t c = 0; c < J; ++c) has_doffset_[c] = any_nonzero(table.d_offsets + c * 3 * S, 3 * S);

  contribution_start_.assign(K + 1, 0);
  closure_start_.assign(K + 1, 0);
  contributions_.reserve(K * 8);
  closure_.reserve(K * 8);
  closure_mask_.assign(K * J, 0);
  for (std::size_t k = 0; k < K; ++k) {
    std::uint8_t* mask = closure_mask_.data() + k * J;
    for (std::size_t d = 0; d < J; ++d) {
      const double a = table.weights[k * J + d];
      const bool marker = any_nonzero(table.markers + (k * J + d) * 3, 3);
      const bool dmarker = any_nonzero(table.d_markers + (k * J + d) * 3 * S, 3 * S);
      if (a == 0.0 && !marker && !dmarker) continue;
      contributions_.push_back({static_cast<std::uint32_t>(d), a, marker, dmarker});
      for (std::int64_t c = static_cast<std::int64_t>(d); c >= 0 && !mask[c]; c = table.parents[c]) mask[c] = 1;
    }
    for (std::size_t c = J; c-- > 0;)
      if (mask[c]) closure_.push_back(static_cast<std::uint32_t>(c));
    contribution_start_[k + 1] = contributions_.size();
    closure_start_[k + 1] = closure_.size();
  }
}

FkWorkspace BodyKernel::make_workspace() const {
  const std::size_t J = table_.num_joints, S = table_.shape_dim;
  FkWorkspace ws;
  ws.rot.assign(J * 9, 0.0);
  ws.pos.assign(J * 3, 0.0);
  ws.axis_map.assign(J * 9, 0.0);
  ws.d_pos.assign(J * 3 * S, 0.0);
  ws.sub_sum.assign(J * 3, 0.0);
  ws.sub_weight.assign(J, 0.0);
  ws.block.assign(J * 9, 0.0);
  return ws;
}

void BodyKernel::pose_frame(const double* root, const double* pose, const FrameOutputs& out,
                            FkWorkspace& ws) const {
  const std::size_t J = table_.num_joints, K = table_.num_keypoints, S = table_.shape_dim;
  const std::size_t P = num_params();
  const std::size_t shape_col = 6 + 3 * (J - 1);
  const bool jac = out.d_joints != nullptr || out.d_keypoints != nullptr;
  const std::int64_t* parents = table_.parents;
  double* G = ws.rot.data();
  double* X = ws.pos.data();
  double* A = ws.axis_map.data();
  double* dX = ws.d_pos.data();

  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) G[3 * i + j] = root[4 * i + j];
    X[i] = root[4 * i + 3];
  }
  if (jac) std::fill(dX, dX + 3 * S, 0.0);
  double local[9], jr[9];
  for (std::size_t c = 1; c < J; ++c) {
    const std::size_t p = static_cast<std::size_t>(parents[c]);
    const double* Gp = G + 9 * p;
    exp_and_right_jacobian(pose + 3 * (c - 1), local, jac ? jr : nullptr);
    mat_mul(Gp, local, G + 9 * c);
    double step[3];
    mat_vec(Gp, table_.offsets + 3 * c, step);
    for (int i = 0; i < 3; ++i) X[3 * c + i] = X[3 * p + i] + step[i];
    if (!jac) continue;
    mat_mul(G + 9 * c, jr, A + 9 * c);
    double* dXc = dX + 3 * S * c;
    std::copy(dX + 3 * S * p, dX + 3 * S * (p + 1), dXc);
    if (has_doffset_[c]) add_rot_times_shape(Gp, table_.d_offsets + 3 * S * c, S, dXc, S);
  }

  if (out.rotations) std::copy(G, G + 9 * J, out.rotations);
  if (out.joints) std::copy(X, X + 3 * J, out.joints);

  const double* R0 = G;
  const double* t0 = X;

  if (out.d_joints) {
    double* blk = ws.block.data();
    for (std::size_t d = 0; d < J; ++d) {
      const std::uint8_t* anc = ancestor_mask_.data() + d * J;
      const double rel[3] = {X[3 * d] - t0[0], X[3 * d + 1] - t0[1], X[3 * d + 2] - t0[2]};
      neg_skew_mul(rel, R0, blk);
      for (std::size_t c = 1; c < J; ++c) {
        if (!anc[c]) continue;
        const double lever[3] = {X[3 * d] - X[3 * c], X[3 * d + 1] - X[3 * c + 1], X[3 * d + 2] - X[3 * c + 2]};
        neg_skew_mul(lever, A + 9 * c, blk + 9 * c);
      }
      for (int i = 0; i < 3; ++i) {
        double* row = out.d_joints + (3 * d + i) * P;
        write_pose_columns(row, i, blk, R0, 1.0, anc, J);
        std::copy(dX + (3 * d + i) * S, dX + (3 * d + i + 1) * S, row + shape_col);
      }
    }
  }

  if (out.keypoints == nullptr && out.d_keypoints == nullptr) return;
  double* sub = ws.sub_sum.data();
  double* subw = ws.sub_weight.data();
  double* blk = ws.block.data();
  for (std::size_t k = 0; k < K; ++k) {
    const Contribution* const contrib_begin = contributions_.data() + contribution_start_[k];
    const Contribution* const contrib_end = contributions_.data() + contribution_start_[k + 1];
    const std::uint32_t* const closure_begin = closure_.data() + closure_start_[k];
    const std::uint32_t* const closure_end = closure_.data() + closure_start_[k + 1];
    for (const std::uint32_t* it = closure_begin; it != closure_end; ++it) {
      const std::uint32_t c = *it;
      sub[3 * c] = sub[3 * c + 1] = sub[3 * c + 2] = 0.0;
      subw[c] = 0.0;
    }
    for (const Contribution* e = contrib_begin; e != contrib_end; ++e) {
      const std::size_t d = e->joint;
      double m[3] = {e->weight * X[3 * d], e->weight * X[3 * d + 1], e->weight * X[3 * d + 2]};
      if (e->has_marker) {
        double g[3];
        mat_vec(G + 9 * d, table_.markers + (k * J + d) * 3, g);
        m[0] += g[0];
        m[1] += g[1];
        m[2] += g[2];
      }
      sub[3 * d] = m[0];
      sub[3 * d + 1] = m[1];
      sub[3 * d + 2] = m[2];
      subw[d] = e->weight;
    }
    // Closure is sorted children first, so each subtree is complete before it joins its parent.
    for (const std::uint32_t* it = closure_begin; it != closure_end; ++it) {
      const std::uint32_t c = *it;
      if (c == 0) continue;
      const std::size_t p = static_cast<std::size_t>(parents[c]);
      sub[3 * p] += sub[3 * c];
      sub[3 * p + 1] += sub[3 * c + 1];
      sub[3 * p + 2] += sub[3 * c + 2];
      subw[p] += subw[c];
    }
    const bool any = closure_begin != closure_end;
    const double point[3] = {any ? sub[0] : 0.0, any ? sub[1] : 0.0, any ? sub[2] : 0.0};
    const double wsum = any ? subw[0] : 0.0;
    if (out.keypoints) {
      out.keypoints[3 * k] = point[0];
      out.keypoints[3 * k + 1] = point[1];
      out.keypoints[3 * k + 2] = point[2];
    }
    if (!out.d_keypoints) continue;

    const std::uint8_t* mask = closure_mask_.data() + k * J;
    const double rel[3] = {point[0] - wsum * t0[0], point[1] - wsum * t0[1], point[2] - wsum * t0[2]};
    neg_skew_mul(rel, R0, blk);
    for (const std::uint32_t* it = closure_begin; it != closure_end; ++it) {
      const std::uint32_t c = *it;
      if (c == 0) continue;
      // Everything below c turns about J_c: lever = sum_{d below c} a_kd (J_d - J_c) + G_d l_kd.
      const double lever[3] = {sub[3 * c] - subw[c] * X[3 * c], sub[3 * c + 1] - subw[c] * X[3 * c + 1],
                               sub[3 * c + 2] - subw[c] * X[3 * c + 2]};
      neg_skew_mul(lever, A + 9 * c, blk + 9 * c);
    }
    double* rows = out.d_keypoints + 3 * k * P;
    for (int i = 0; i < 3; ++i) {
      double* row = rows + i * P;
      write_pose_columns(row, i, blk, R0, wsum, mask, J);
      std::fill(row + shape_col, row + P, 0.0);
    }
    if (S == 0) continue;
    for (const Contribution* e = contrib_begin; e != contrib_end; ++e) {
      const std::size_t d = e->joint;
      if (e->weight != 0.0) {
        for (int i = 0; i < 3; ++i) {
          double* o = rows + i * P + shape_col;
          const double* src = dX + (3 * d + i) * S;
          for (std::size_t s = 0; s < S; ++s) o[s] += e->weight * src[s];
        }
      }
      if (e->has_dmarker)
        add_rot_times_shape(G + 9 * d, table_.d_markers + (k * J + d) * 3 * S, S, rows + shape_col, P);
    }
  }
}

void BodyKernel::pose_frames(std::size_t frames, const double* root, const double* pose,
                             const FrameOutputs& out) const {
  const std::size_t J = table_.num_joints, K = table_.num_keypoints, P = num_params();
  FkWorkspace ws = make_workspace();
  for (std::size_t t = 0; t < frames; ++t) {
    FrameOutputs f;
    f.joints = out.joints ? out.joints + t * J * 3 : nullptr;
    f.keypoints = out.keypoints ? out.keypoints + t * K * 3 : nullptr;
    f.rotations = out.rotations ? out.rotations + t * J * 9 : nullptr;
    f.d_joints = out.d_joints ? out.d_joints + t * J * 3 * P : nullptr;
    f.d_keypoints = out.d_keypoints ? out.d_keypoints + t * K * 3 * P : nullptr;
    pose_frame(root + 16 * t, pose + 3 * (J - 1) * t, f, ws);
  }
}

}  // namespace mocapgraph
