// SO(3) helpers shared by the native kernels: exponential map with its right Jacobian, the
// logarithm, the inverse right Jacobian and 3x3 products. Matrices are 3x3 row-major.
#pragma once

#include <cmath>

namespace mocapgraph {

// Same switch-over as mocapgraph/body/rotations.py; with the theta^4 terms kept the series are
// exact to round-off there.
constexpr double kSmallAngle = 1e-4;

// Exp(theta) and, if jr != nullptr, the right Jacobian Jr(theta); both 3x3 row-major.
inline void exp_and_right_jacobian(const double* th, double* R, double* jr) {
  const double x = th[0], y = th[1], z = th[2];
  const double t2 = x * x + y * y + z * z;
  double a, b, c;  // sin t / t, (1 - cos t) / t^2, (t - sin t) / t^3
  if (t2 < kSmallAngle * kSmallAngle) {
    a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0;
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0;
    c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0;
  } else {
    const double t = std::sqrt(t2);
    const double s = std::sin(t);
    const double h = std::sin(0.5 * t);
    a = s / t;
    // 1 - cos t written as 2 sin^2(t/2): no cancellation for small t.
    b = 2.0 * h * h / t2;
    c = (t - s) / (t2 * t);
  }
  // K = [th]x, K^2 = th th^T - t^2 I.
  const double kk[9] = {x * x - t2, x * y, x * z, x * y, y * y - t2, y * z, x * z, y * z, z * z - t2};
  const double k[9] = {0.0, -z, y, z, 0.0, -x, -y, x, 0.0};
  for (int i = 0; i < 9; ++i) R[i] = a * k[i] + b * kk[i];
  R[0] += 1.0;
  R[4] += 1.0;
  R[8] += 1.0;
  if (jr != nullptr) {
    for (int i = 0; i < 9; ++i) jr[i] = -b * k[i] + c * kk[i];
    jr[0] += 1.0;
    jr[4] += 1.0;
    jr[8] += 1.0;
  }
}

// C = A B for 3x3 row-major matrices.
inline void mat_mul(const double* A, const double* B, double* C) {
  for (int i = 0; i < 3; ++i) {
    const double a0 = A[3 * i], a1 = A[3 * i + 1], a2 = A[3 * i + 2];
    C[3 * i + 0] = a0 * B[0] + a1 * B[3] + a2 * B[6];
    C[3 * i + 1] = a0 * B[1] + a1 * B[4] + a2 * B[7];
    C[3 * i + 2] = a0 * B[2] + a1 * B[5] + a2 * B[8];
  }
}

// C = A^T B for 3x3 row-major matrices.
inline void mat_tmul(const double* A, const double* B, double* C) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) C[3 * i + j] = A[i] * B[j] + A[3 + i] * B[3 + j] + A[6 + i] * B[6 + j];
}

// Log(R): the axis-angle vector (angle in [0, pi]) of a rotation matrix, through its unit
// quaternion (Shepperd's choice of the largest component, then atan2), accurate at every angle.
inline void log_map(const double* R, double* th) {
  const double tr = R[0] + R[4] + R[8];
  double w, x, y, z;
  if (tr >= R[0] && tr >= R[4] && tr >= R[8]) {
    const double s = 2.0 * std::sqrt(1.0 + tr);
    w = 0.25 * s;
    x = (R[7] - R[5]) / s;
    y = (R[2] - R[6]) / s;
    z = (R[3] - R[1]) / s;
  } else if (R[0] >= R[4] && R[0] >= R[8]) {
    const double s = 2.0 * std::sqrt(1.0 + R[0] - R[4] - R[8]);
    w = (R[7] - R[5]) / s;
    x = 0.25 * s;
    y = (R[1] + R[3]) / s;
    z = (R[2] + R[6]) / s;
  } else if (R[4] >= R[8]) {
    const double s = 2.0 * std::sqrt(1.0 + R[4] - R[0] - R[8]);
    w = (R[2] - R[6]) / s;
    x = (R[1] + R[3]) / s;
    y = 0.25 * s;
    z = (R[5] + R[7]) / s;
  } else {
    const double s = 2.0 * std::sqrt(1.0 + R[8] - R[0] - R[4]);
    w = (R[3] - R[1]) / s;
    x = (R[2] + R[6]) / s;
    y = (R[5] + R[7]) / s;
    z = 0.25 * s;
  }
  if (w < 0.0) {  // the same rotation; w >= 0 gives the angle in [0, pi]
    w = -w;
    x = -x;
    y = -y;
    z = -z;
  }
  const double v = std::sqrt(x * x + y * y + z * z);
  // angle / v = 2 atan2(v, w) / v, with its series where v is tiny (then w ~ 1).
  const double f = v < kSmallAngle ? 2.0 / w * (1.0 - v * v / (3.0 * w * w)) : 2.0 * std::atan2(v, w) / v;
  th[0] = f * x;
  th[1] = f * y;
  th[2] = f * z;
}

// Jr(theta)^-1 = I + [theta]x / 2 + (1/t^2 - cot(t/2) / (2t)) [theta]x^2, finite up to t = pi.
inline void right_jacobian_inverse(const double* th, double* out) {
  const double x = th[0], y = th[1], z = th[2];
  const double t2 = x * x + y * y + z * z;
  double d;
  if (t2 < kSmallAngle * kSmallAngle) {
    d = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0;
  } else {
    const double t = std::sqrt(t2);
    d = 1.0 / t2 - std::cos(0.5 * t) / (std::sin(0.5 * t) * 2.0 * t);
  }
  const double kk[9] = {x * x - t2, x * y, x * z, x * y, y * y - t2, y * z, x * z, y * z, z * z - t2};
  const double k[9] = {0.0, -z, y, z, 0.0, -x, -y, x, 0.0};
  for (int i = 0; i < 9; ++i) out[i] = 0.5 * k[i] + d * kk[i];
  out[0] += 1.0;
  out[4] += 1.0;
  out[8] += 1.0;
}

}  // namespace mocapgraph
