// A root pose between two poses of a time grid, with the Jacobians of the interpolation
// (native kernel of mocapgraph/factors/interpolation.py, which gives the formulas).
//
// Rotation by slerp, R_a = R0 Exp(a Log(R0^T R1)); translation linear. Tangents are GTSAM's
// Pose3 ones, [w, v] rotation first, both in the body frame (R <- R Exp(w), t <- t + R v).
#pragma once

namespace mocapgraph {

// first, second, out: (4, 4) row-major world_T_root; d_first, d_second: (6, 6) row-major
// d xi_a / d xi_first and d xi_a / d xi_second.
void interpolate_pose(const double* first, const double* second, double fraction, double* out,
                      double* d_first, double* d_second);

}  // namespace mocapgraph
