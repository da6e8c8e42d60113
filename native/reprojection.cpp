#include "reprojection.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace mocapgraph {

void reproject_frame(const BodyKernel& body, const ReprojectionInputs& in,
                     const ReprojectionOutputs& out) {
  const std::size_t K = body.num_keypoints(), C = in.num_cameras, P = body.num_params();
  const std::size_t width = P + 6 * C;
  const bool jac = out.jacobian != nullptr;
  const double sigma = in.gm_sigma_px;
  const bool robust = sigma > 0.0 && std::isfinite(sigma);

  // The body does not depend on the camera: pose it once for all C views.
  std::vector<double> points(3 * K);
  std::vector<double> d_points(jac ? 3 * K * P : 0);
  FkWorkspace ws = body.make_workspace();
  FrameOutputs fk;
  fk.keypoints = points.data();
  fk.d_keypoints = jac ? d_points.data() : nullptr;
  body.pose_frame(in.root, in.pose, fk, ws);

  for (std::size_t c = 0; c < C; ++c) {
    const double* cam = in.cameras + 16 * c;
    const double Rc[9] = {cam[0], cam[1], cam[2], cam[4], cam[5], cam[6], cam[8], cam[9], cam[10]};
    const double tc[3] = {cam[3], cam[7], cam[11]};
    const double fx = in.intrinsics[4 * c], fy = in.intrinsics[4 * c + 1];
    const double cx = in.intrinsics[4 * c + 2], cy = in.intrinsics[4 * c + 3];
    for (std::size_t k = 0; k < K; ++k) {
      const std::size_t obs = c * K + k;
      double* res = out.residual + 2 * obs;
      double* rows = jac ? out.jacobian + 2 * obs * width : nullptr;
      const double ou = in.observed[2 * obs], ov = in.observed[2 * obs + 1];
      const double w = in.obs_weights[obs];
      const double* X = points.data() + 3 * k;
      const double d[3] = {X[0] - tc[0], X[1] - tc[1], X[2] - tc[2]};
      // p = R_c^T d
      const double p[3] = {Rc[0] * d[0] + Rc[3] * d[1] + Rc[6] * d[2],
                           Rc[1] * d[0] + Rc[4] * d[1] + Rc[7] * d[2],
                           Rc[2] * d[0] + Rc[5] * d[1] + Rc[8] * d[2]};
      // `>=` rather than `!(<)` so that a NaN depth counts as invalid too.
      const bool ok = !std::isnan(ou) && !std::isnan(ov) && w != 0.0 && p[2] >= in.min_depth;
      out.valid[obs] = ok;
      if (!ok) {
        res[0] = res[1] = 0.0;
        if (jac) std::fill(rows, rows + 2 * width, 0.0);
        continue;
      }
      const double iz = 1.0 / p[2];
      const double e[2] = {fx * p[0] * iz + cx - ou, fy * p[1] * iz + cy - ov};
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
      if (!jac) continue;

      // de/dp = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]
      const double dedp[6] = {fx * iz, 0.0, -fx * p[0] * iz * iz, 0.0, fy * iz, -fy * p[1] * iz * iz};
      double drdp[6];
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j) drdp[3 * i + j] = drde[2 * i] * dedp[j] + drde[2 * i + 1] * dedp[3 + j];
      // dr/dX = dr/dp R_c^T
      double drdx[6];
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
          drdx[3 * i + j] = drdp[3 * i] * Rc[3 * j] + drdp[3 * i + 1] * Rc[3 * j + 1] + drdp[3 * i + 2] * Rc[3 * j + 2];
      const double* dX = d_points.data() + 3 * k * P;
      for (int i = 0; i < 2; ++i) {
        double* row = rows + i * width;
        const double b0 = drdx[3 * i], b1 = drdx[3 * i + 1], b2 = drdx[3 * i + 2];
        for (std::size_t q = 0; q < P; ++q) row[q] = b0 * dX[q] + b1 * dX[P + q] + b2 * dX[2 * P + q];
        std::fill(row + P, row + width, 0.0);
        // dp/dw = [p]x, dp/dv = -I
        double* cc = row + P + 6 * c;
        const double g0 = drdp[3 * i], g1 = drdp[3 * i + 1], g2 = drdp[3 * i + 2];
        cc[0] = g1 * p[2] - g2 * p[1];
        cc[1] = g2 * p[0] - g0 * p[2];
        cc[2] = g0 * p[1] - g1 * p[0];
        cc[3] = -g0;
        cc[4] = -g1;
        cc[5] = -g2;
      }
    }
  }
}

}  // namespace mocapgraph
