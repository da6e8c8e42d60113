#include "interpolation.h"

#include <algorithm>

#include "so3.h"

namespace mocapgraph {

void interpolate_pose(const double* first, const double* second, double fraction, double* out,
                      double* d_first, double* d_second) {
  const double a = fraction;
  double R0[9], R1[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      R0[3 * i + j] = first[4 * i + j];
      R1[3 * i + j] = second[4 * i + j];
    }
  double relative[9], delta[3], partial_delta[3], E[9], jr[9], jr_inv[9], J[9], Ra[9];
  mat_tmul(R0, R1, relative);  // R0^T R1
  log_map(relative, delta);
  for (int i = 0; i < 3; ++i) partial_delta[i] = a * delta[i];
  exp_and_right_jacobian(partial_delta, E, jr);
  right_jacobian_inverse(delta, jr_inv);
  mat_mul(jr, jr_inv, J);
  mat_mul(R0, E, Ra);

  std::fill(out, out + 16, 0.0);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out[4 * i + j] = Ra[3 * i + j];
    out[4 * i + 3] = (1.0 - a) * first[4 * i + 3] + a * second[4 * i + 3];
  }
  out[15] = 1.0;

  // With R_a = R0 E: d w_a/d w0 = E^T - a J (R0^T R1)^T, d w_a/d w1 = a J,
  // d v_a/d v0 = (1 - a) R_a^T R0 = (1 - a) E^T, d v_a/d v1 = a R_a^T R1 = a E^T R0^T R1.
  double JRt[9], EtRel[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      JRt[3 * i + j] = J[3 * i] * relative[3 * j] + J[3 * i + 1] * relative[3 * j + 1] + J[3 * i + 2] * relative[3 * j + 2];
  mat_tmul(E, relative, EtRel);
  std::fill(d_first, d_first + 36, 0.0);
  std::fill(d_second, d_second + 36, 0.0);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      d_first[6 * i + j] = E[3 * j + i] - a * JRt[3 * i + j];
      d_second[6 * i + j] = a * J[3 * i + j];
      d_first[6 * (i + 3) + j + 3] = (1.0 - a) * E[3 * j + i];
      d_second[6 * (i + 3) + j + 3] = a * EtRel[3 * i + j];
    }
}

}  // namespace mocapgraph
