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

// The reprojection factor's evaluation (mocapgraph/factors/reprojection.py) in one pass: the
// labelling hypothesis of each camera, then only the rows of usable observations.
//
// `in.obs_weights` are the detections' weights; body point k of camera c reads detection
// perm[k] of the camera's chosen permutation, with weight obs_weights[c, perm[k]] * mapped[k].
// Usable: a finite detection with weight > 0 (whether or not the body has the point or it is in
// front: those rows are zero). A permutation keeps a camera's number of usable detections, so
// the row count does not depend on the choice (factor_rows).
struct FactorInputs {
  ReprojectionInputs frame;
  const double* mapped = nullptr;             // (K,) 1 where the body has point k, else 0
  std::size_t num_hypotheses = 0;             // H; 0: the points as detected
  const std::int64_t* permutations = nullptr; // (H, K), row 0 the identity
  const bool* allowed = nullptr;              // (C, H) or null for all
  double relabel_cost = 0.0;                  // added to the cost of every hypothesis but the first
  bool relabel = false;                       // choose per camera (else hypothesis 0 everywhere)
  bool cost_row = false;                      // append sqrt(2 relabel_cost * #relabelled cameras)
  const std::int64_t* focal_columns = nullptr;  // (C,) a camera's focal column (-1: none) or null
  std::size_t num_focal = 0;                  // F focal columns after the 6 C camera columns
};

struct FactorOutputs {
  double* residual = nullptr;      // (R,)
  double* jacobian = nullptr;      // (R, P + 6 C + F) or null
  std::int64_t* choice = nullptr;  // (C,) the hypothesis each camera took
};

// R: two per usable observation, plus the cost row.
std::size_t factor_rows(std::size_t num_keypoints, const FactorInputs& in);

// Choice of hypothesis: per camera, the lowest robust cost 1/2 sum w^2 rho(|e|^2) over the
// points in front of it at the current state, plus relabel_cost for any but the first (ties: the
// lower index). The focal column of camera c holds dr/ds for fx, fy = e^s (fx0, fy0).
void reproject_factor(const BodyKernel& body, const FactorInputs& in, const FactorOutputs& out);

}  // namespace mocapgraph
