// Multi-camera reprojection residual of one frame's body keypoints, Geman-McClure weighted,
// with Jacobians (native kernel of mocapgraph/factors/reprojection_kernel.py).
//
// Cameras are world_T_camera poses (R_c, t_c) of OpenCV cameras (x right, y down, z forward):
//   p = R_c^T (X - t_c),  u = fx p.x / p.z + cx,  v = fy p.y / p.z + cy,  e = (u, v) - observed.
// Robust residual r = w e s with s = sigma / sqrt(sigma^2 + |e|^2) (plain r = w e when sigma is
// inf or <= 0). Rows are camera-major: row 2 (c K + k) + {0, 1}. Columns: the P body columns of
// body_kernels.h, then 6 per camera: right perturbation of world_T_camera, rotation first
// (R_c <- R_c Exp(w), t_c <- t_c + R_c v).
#pragma once

#include <cstddef>
#include <cstdint>

#include "body_kernels.h"

namespace mocapgraph {

struct ReprojectionInputs {
  const double* root = nullptr;         // (4, 4) world_T_root
  const double* pose = nullptr;         // (J-1, 3) local axis-angle, radians
  std::size_t num_cameras = 0;          // C
  const double* cameras = nullptr;      // (C, 4, 4) world_T_camera, metres
  const double* intrinsics = nullptr;   // (C, 4) fx, fy, cx, cy in pixels
  const double* observed = nullptr;     // (C, K, 2) pixels, NaN = missing
  const double* obs_weights = nullptr;  // (C, K) >= 0
  double gm_sigma_px = 0.0;             // Geman-McClure scale in pixels; inf or <= 0 = plain
  double min_depth = 0.05;              // points with p.z < min_depth (metres) are invalid
};

struct ReprojectionOutputs {
  double* residual = nullptr;  // (C K 2,)
  double* jacobian = nullptr;  // (C K 2, P + 6 C) or null to skip Jacobians
  bool* valid = nullptr;       // (C, K)
};

// Poses the body once and projects it into every camera. Invalid keypoints (NaN observation,
// zero weight, too close or behind the camera) get exactly zero residual and Jacobian rows.
void reproject_frame(const BodyKernel& body, const ReprojectionInputs& in,
                     const ReprojectionOutputs& out);

}  // namespace mocapgraph
