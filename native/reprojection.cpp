#include "reprojection.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace mocapgraph {
namespace {

// One camera: world_T_camera split into R_c and t_c, and its intrinsics.
struct View {
  double R[9];
  double t[3];
  double fx, fy, cx, cy;
};

View make_view(const double* cam, const double* intrinsics) {
  return {{cam[0], cam[1], cam[2], cam[4], cam[5], cam[6], cam[8], cam[9], cam[10]},
          {cam[3], cam[7], cam[11]},
          intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]};
}

// p = R_c^T (X - t_c)
inline void camera_point(const View& v, const double* X, double* p) {
  const double d[3] = {X[0] - v.t[0], X[1] - v.t[1], X[2] - v.t[2]};
  const double* R = v.R;
  p[0] = R[0] * d[0] + R[3] * d[1] + R[6] * d[2];
  p[1] = R[1] * d[0] + R[4] * d[1] + R[7] * d[2];
  p[2] = R[2] * d[0] + R[5] * d[1] + R[8] * d[2];
}

// Residual (2) of a valid observation (ou, ov) with weight w of the point at p in the camera
// and, when `rows` is set, its two Jacobian rows of `width` columns: the P body columns from
// dX (3, P), the camera's six at `cam_col`, the focal log scale's at `focal_col` (if >= 0),
// zeros elsewhere.
void observation_rows(const View& v, const double* p, const double* dX, std::size_t P, std::size_t width,
                      std::size_t cam_col, std::ptrdiff_t focal_col, double ou, double ov, double w, double sigma,
                      bool robust, double* res, double* rows) {
  const double iz = 1.0 / p[2];
  const double e[2] = {v.fx * p[0] * iz + v.cx - ou, v.fy * p[1] * iz + v.cy - ov};
  // dr/de = w s (I - e e^T / (sigma^2 + |e|^2)); identity scaled by w when not robust.
  double drde[4];
  if (robust) {
    const double denom = sigma * sigma + e[0] * e[0] + e[1] * e[1];
    const double s = sigma / std::sqrt(denom);
    const double ws_ = w * s;
    res[0] = ws_ * e[0];
    res[1] = ws_ * e[1];
    drde[0] = ws_ * (1.0 - e[0] * e[0] / denom);
    drde[1] = -ws_ * e[0] * e[1] / denom;
    drde[2] = drde[1];
    drde[3] = ws_ * (1.0 - e[1] * e[1] / denom);
  } else {
    res[0] = w * e[0];
    res[1] = w * e[1];
    drde[0] = w;
    drde[1] = drde[2] = 0.0;
    drde[3] = w;
  }
  if (rows == nullptr) return;

  // de/dp = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]
  const double dedp[6] = {v.fx * iz, 0.0, -v.fx * p[0] * iz * iz, 0.0, v.fy * iz, -v.fy * p[1] * iz * iz};
  double drdp[6];
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j) drdp[3 * i + j] = drde[2 * i] * dedp[j] + drde[2 * i + 1] * dedp[3 + j];
  // dr/dX = dr/dp R_c^T
  const double* Rc = v.R;
  double drdx[6];
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j)
      drdx[3 * i + j] = drdp[3 * i] * Rc[3 * j] + drdp[3 * i + 1] * Rc[3 * j + 1] + drdp[3 * i + 2] * Rc[3 * j + 2];
  // d(u - cx, v - cy)/ds = (u - cx, v - cy) for fx, fy = e^s (fx0, fy0)
  const double centred[2] = {v.fx * p[0] * iz, v.fy * p[1] * iz};
  for (int i = 0; i < 2; ++i) {
    double* row = rows + i * width;
    const double b0 = drdx[3 * i], b1 = drdx[3 * i + 1], b2 = drdx[3 * i + 2];
    for (std::size_t q = 0; q < P; ++q) row[q] = b0 * dX[q] + b1 * dX[P + q] + b2 * dX[2 * P + q];
    std::fill(row + P, row + width, 0.0);
    // dp/dw = [p]x, dp/dv = -I
    double* cc = row + cam_col;
    const double g0 = drdp[3 * i], g1 = drdp[3 * i + 1], g2 = drdp[3 * i + 2];
    cc[0] = g1 * p[2] - g2 * p[1];
    cc[1] = g2 * p[0] - g0 * p[2];
    cc[2] = g0 * p[1] - g1 * p[0];
    cc[3] = -g0;
    cc[4] = -g1;
    cc[5] = -g2;
    if (focal_col >= 0) row[focal_col] = drde[2 * i] * centred[0] + drde[2 * i + 1] * centred[1];
  }
}

bool is_robust(double sigma) { return sigma > 0.0 && std::isfinite(sigma); }

// The body's keypoints (K, 3) and, if d_points is set, their derivatives (K, 3, P).
void pose_points(const BodyKernel& body, const ReprojectionInputs& in, std::vector<double>& points,
                 std::vector<double>* d_points) {
  const std::size_t K = body.num_keypoints(), P = body.num_params();
  points.assign(3 * K, 0.0);
  if (d_points) d_points->assign(3 * K * P, 0.0);
  FkWorkspace ws = body.make_workspace();
  FrameOutputs fk;
  fk.keypoints = points.data();
  fk.d_keypoints = d_points ? d_points->data() : nullptr;
  body.pose_frame(in.root, in.pose, fk, ws);
}

}  // namespace

void reproject_frame(const BodyKernel& body, const ReprojectionInputs& in,
                     const ReprojectionOutputs& out) {
  const std::size_t K = body.num_keypoints(), C = in.num_cameras, P = body.num_params();
  const std::size_t width = P + 6 * C;
  const bool jac = out.jacobian != nullptr;
  const bool robust = is_robust(in.gm_sigma_px);

  // The body does not depend on the camera: pose it once for all C views.
  std::vector<double> points, d_points;
  pose_points(body, in, points, jac ? &d_points : nullptr);

  for (std::size_t c = 0; c < C; ++c) {
    const View v = make_view(in.cameras + 16 * c, in.intrinsics + 4 * c);
    for (std::size_t k = 0; k < K; ++k) {
      const std::size_t obs = c * K + k;
      double* res = out.residual + 2 * obs;
      double* rows = jac ? out.jacobian + 2 * obs * width : nullptr;
      const double ou = in.observed[2 * obs], ov = in.observed[2 * obs + 1];
      const double w = in.obs_weights[obs];
      double p[3];
      camera_point(v, points.data() + 3 * k, p);
      // `>=` rather than `!(<)` so that a NaN depth counts as invalid too.
      const bool ok = !std::isnan(ou) && !std::isnan(ov) && w != 0.0 && p[2] >= in.min_depth;
      out.valid[obs] = ok;
      if (!ok) {
        res[0] = res[1] = 0.0;
        if (jac) std::fill(rows, rows + 2 * width, 0.0);
        continue;
      }
      observation_rows(v, p, jac ? d_points.data() + 3 * k * P : nullptr, P, width, P + 6 * c, -1, ou, ov, w,
                       in.gm_sigma_px, robust, res, rows);
    }
  }
}

std::size_t factor_rows(std::size_t num_keypoints, const FactorInputs& in) {
  const ReprojectionInputs& f = in.frame;
  std::size_t rows = in.cost_row ? 1 : 0;
  for (std::size_t i = 0; i < f.num_cameras * num_keypoints; ++i)
    if (!std::isnan(f.observed[2 * i]) && !std::isnan(f.observed[2 * i + 1]) && f.obs_weights[i] > 0.0) rows += 2;
  return rows;
}

void reproject_factor(const BodyKernel& body, const FactorInputs& in, const FactorOutputs& out) {
  const ReprojectionInputs& f = in.frame;
  const std::size_t K = body.num_keypoints(), C = f.num_cameras, P = body.num_params();
  const std::size_t width = P + 6 * C + in.num_focal;
  const bool jac = out.jacobian != nullptr;
  const double sigma = f.gm_sigma_px;
  const bool robust = is_robust(sigma);
  const bool choose = in.relabel && robust && in.num_hypotheses > 1;

  std::vector<double> points, d_points;
  pose_points(body, f, points, jac ? &d_points : nullptr);
  std::vector<double> p(3 * K);  // the points in the current camera
  std::vector<std::int64_t> identity(K);
  for (std::size_t k = 0; k < K; ++k) identity[k] = static_cast<std::int64_t>(k);

  std::size_t r = 0, relabelled = 0;
  for (std::size_t c = 0; c < C; ++c) {
    const View v = make_view(f.cameras + 16 * c, f.intrinsics + 4 * c);
    const double* observed = f.observed + 2 * K * c;
    const double* weights = f.obs_weights + K * c;
    for (std::size_t k = 0; k < K; ++k) camera_point(v, points.data() + 3 * k, p.data() + 3 * k);

    std::size_t h_best = 0;
    if (choose) {
      const double sigma2 = sigma * sigma;
      double best = std::numeric_limits<double>::infinity();
      for (std::size_t h = 0; h < in.num_hypotheses; ++h) {
        if (in.allowed && !in.allowed[c * in.num_hypotheses + h]) continue;
        const std::int64_t* perm = in.permutations + h * K;
        double cost = 0.0;
        for (std::size_t k = 0; k < K; ++k) {
          const double* q = p.data() + 3 * k;
          const std::size_t j = static_cast<std::size_t>(perm[k]);
          const double w = weights[j] * in.mapped[k];
          if (!(in.mapped[k] != 0.0 && q[2] >= f.min_depth && w > 0.0)) continue;
          const double iz = 1.0 / q[2];
          const double e0 = v.fx * q[0] * iz + v.cx - observed[2 * j];
          const double e1 = v.fy * q[1] * iz + v.cy - observed[2 * j + 1];
          const double e2 = e0 * e0 + e1 * e1;
          if (!std::isfinite(e2)) continue;  // a missing detection
          cost += w * w * (sigma2 * e2 / (sigma2 + e2));
        }
        cost *= 0.5;
        if (h > 0) cost += in.relabel_cost;
        if (cost < best) best = cost, h_best = h;
      }
    }
    out.choice[c] = static_cast<std::int64_t>(h_best);
    relabelled += h_best != 0;
    const std::int64_t* perm = in.num_hypotheses ? in.permutations + h_best * K : identity.data();
    const std::ptrdiff_t focal_col = in.focal_columns && in.focal_columns[c] >= 0
                                         ? static_cast<std::ptrdiff_t>(P + 6 * C + in.focal_columns[c])
                                         : -1;
    for (std::size_t k = 0; k < K; ++k) {
      const std::size_t j = static_cast<std::size_t>(perm[k]);
      const double ou = observed[2 * j], ov = observed[2 * j + 1];
      if (std::isnan(ou) || std::isnan(ov) || !(weights[j] > 0.0)) continue;  // no rows at all
      const double w = weights[j] * in.mapped[k];
      double* res = out.residual + r;
      double* rows = jac ? out.jacobian + r * width : nullptr;
      r += 2;
      const double* q = p.data() + 3 * k;
      if (!(w != 0.0 && q[2] >= f.min_depth)) {  // zero rows: the body lacks the point, or it is behind
        res[0] = res[1] = 0.0;
        if (jac) std::fill(rows, rows + 2 * width, 0.0);
        continue;
      }
      observation_rows(v, q, jac ? d_points.data() + 3 * k * P : nullptr, P, width, P + 6 * c, focal_col, ou, ov, w,
                       sigma, robust, res, rows);
    }
  }
  if (in.cost_row) {
    out.residual[r] = std::sqrt(2.0 * in.relabel_cost * static_cast<double>(relabelled));
    if (jac) std::fill(out.jacobian + r * width, out.jacobian + (r + 1) * width, 0.0);
  }
}

}  // namespace mocapgraph
