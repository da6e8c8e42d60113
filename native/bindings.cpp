// Python module mocapgraph._native: thin, validating wrappers around the native kernels.
//
// Every argument's shape is checked here (a ValueError names the argument) so that no
// Python input can make a kernel read or write out of bounds. Results are new numpy arrays.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

#include "body_kernels.h"
#include "interpolation.h"
#include "reprojection.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace {

using InF = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
using InI = nb::ndarray<const std::int64_t, nb::c_contig, nb::device::cpu>;

constexpr std::int64_t kAny = -1;

std::string shape_text(const std::vector<std::int64_t>& shape) {
  std::string s = "(";
  for (std::size_t i = 0; i < shape.size(); ++i) {
    if (i) s += ", ";
    s += shape[i] < 0 ? std::string("N") : std::to_string(shape[i]);
  }
  if (shape.size() == 1) s += ",";
  return s + ")";
}

// Throws ValueError (std::invalid_argument) naming `name` unless `a` has `expected` (kAny = any).
template <class Array>
void check_shape(const Array& a, const char* name, const std::vector<std::int64_t>& expected) {
  bool ok = a.ndim() == expected.size();
  for (std::size_t i = 0; ok && i < expected.size(); ++i)
    ok = expected[i] < 0 || static_cast<std::int64_t>(a.shape(i)) == expected[i];
  if (ok) return;
  std::vector<std::int64_t> got;
  for (std::size_t i = 0; i < a.ndim(); ++i) got.push_back(static_cast<std::int64_t>(a.shape(i)));
  throw std::invalid_argument(std::string(name) + ": expected shape " + shape_text(expected) +
                              ", got " + shape_text(got));
}

// Recycles large output buffers between calls.
//
// Jacobian outputs are megabytes per call, and freshly mapped memory costs a page fault per
// 4 KiB on first touch; in a loop over batches those faults cost more than the kinematics
// itself. Buffers released by numpy (the capsule deleter) are kept, up to kBudget bytes, and
// handed to the next call that needs a buffer of at most that size.
class BufferPool {
 public:
  static BufferPool& instance() {
    // Leaked on purpose: arrays can outlive module teardown and still release into the pool.
    static BufferPool* pool = new BufferPool;
    return *pool;
  }

  // Returns a pointer to `bytes` usable bytes, 64-byte aligned.
  void* acquire(std::size_t bytes) {
    if (bytes >= kMinPooled) {
      std::lock_guard<std::mutex> lock(mutex_);
      // Best fit among cached buffers no more than twice as large as requested.
      std::size_t best = free_.size();
      for (std::size_t i = 0; i < free_.size(); ++i) {
        const std::size_t cap = capacity(free_[i]);
        if (cap >= bytes && cap <= 2 * bytes && (best == free_.size() || cap < capacity(free_[best]))) best = i;
      }
      if (best != free_.size()) {
        void* data = free_[best];
        cached_bytes_ -= capacity(data);
        free_[best] = free_.back();
        free_.pop_back();
        return data;
      }
    }
    void* base = std::malloc(kHeader + (bytes == 0 ? 1 : bytes));
    if (base == nullptr) throw std::bad_alloc();
    *static_cast<std::size_t*>(base) = bytes;
    return static_cast<char*>(base) + kHeader;
  }

  void release(void* data) noexcept {
    const std::size_t cap = capacity(data);
    if (cap >= kMinPooled) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (cached_bytes_ + cap <= kBudget) {
        try {
          free_.push_back(data);
          cached_bytes_ += cap;
          return;
        } catch (...) {
        }
      }
    }
    std::free(static_cast<char*>(data) - kHeader);
  }

 private:
  static constexpr std::size_t kHeader = 64;  // keeps the data 64-byte aligned after the size
  static constexpr std::size_t kMinPooled = std::size_t(64) << 10;
  static constexpr std::size_t kBudget = std::size_t(96) << 20;

  static std::size_t capacity(void* data) {
    return *reinterpret_cast<std::size_t*>(static_cast<char*>(data) - kHeader);
  }

  std::mutex mutex_;
  std::vector<void*> free_;
  std::size_t cached_bytes_ = 0;
};

// An output buffer that becomes the owner of a numpy array once handed to to_numpy.
template <class T>
class Buffer {
 public:
  explicit Buffer(std::vector<std::size_t> dims) : shape_(std::move(dims)) {
    std::size_t n = 1;
    for (std::size_t d : shape_) n *= d;
    data_ = static_cast<T*>(BufferPool::instance().acquire(n * sizeof(T)));
  }
  ~Buffer() {
    if (data_) BufferPool::instance().release(data_);
  }
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  T* get() { return data_; }

  nb::object to_numpy() {
    T* raw = data_;
    nb::capsule owner(raw, [](void* p) noexcept { BufferPool::instance().release(p); });
    data_ = nullptr;
    return nb::ndarray<nb::numpy, T>(raw, shape_.size(), shape_.data(), owner).cast();
  }

 private:
  std::vector<std::size_t> shape_;
  T* data_ = nullptr;
};

// Throws ValueError naming `name` (and the index if `indexed`) unless the 3x3 block of each
// (4, 4) transform is a rotation.
void check_rotations(const double* transforms, std::size_t count, const char* name, bool indexed) {
  for (std::size_t n = 0; n < count; ++n) {
    const double* T = transforms + 16 * n;
    const double r[3][3] = {{T[0], T[1], T[2]}, {T[4], T[5], T[6]}, {T[8], T[9], T[10]}};
    double err = 0.0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const double dot = r[i][0] * r[j][0] + r[i][1] * r[j][1] + r[i][2] * r[j][2];
        err = std::max(err, std::abs(dot - (i == j ? 1.0 : 0.0)));
      }
    const double det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) -
                       r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0]) +
                       r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    err = std::max(err, std::abs(det - 1.0));
    if (!(err <= 1e-6)) {
      char detail[64];
      std::snprintf(detail, sizeof detail, "(orthonormality/determinant error %.2g)", err);
      const std::string which = indexed ? "[" + std::to_string(n) + "]" : "";
      throw std::invalid_argument(std::string(name) + which + ": rotation block is not a rotation " + detail);
    }
  }
}

// Validates the six table arrays against each other and returns the kernel's view of them.
mocapgraph::BodyTableView table_view(const InI& parents, const InF& offsets, const InF& d_offsets,
                                     const InF& weights, const InF& markers, const InF& d_markers) {
  if (parents.ndim() != 1 || parents.shape(0) == 0)
    throw std::invalid_argument("parents: expected a non-empty 1-D int64 array");
  const std::int64_t J = static_cast<std::int64_t>(parents.shape(0));
  if (d_offsets.ndim() != 3)
    throw std::invalid_argument("d_offsets: expected shape (" + std::to_string(J) + ", 3, S), got " +
                                std::to_string(d_offsets.ndim()) + " dimensions");
  if (weights.ndim() != 2)
    throw std::invalid_argument("weights: expected shape (K, " + std::to_string(J) + "), got " +
                                std::to_string(weights.ndim()) + " dimensions");
  const std::int64_t S = static_cast<std::int64_t>(d_offsets.shape(2));
  const std::int64_t K = static_cast<std::int64_t>(weights.shape(0));
  check_shape(offsets, "offsets", {J, 3});
  check_shape(d_offsets, "d_offsets", {J, 3, S});
  check_shape(weights, "weights", {K, J});
  check_shape(markers, "markers", {K, J, 3});
  check_shape(d_markers, "d_markers", {K, J, 3, S});
  mocapgraph::BodyTableView v;
  v.num_joints = static_cast<std::size_t>(J);
  v.num_keypoints = static_cast<std::size_t>(K);
  v.shape_dim = static_cast<std::size_t>(S);
  v.parents = parents.data();
  v.offsets = offsets.data();
  v.d_offsets = d_offsets.data();
  v.weights = weights.data();
  v.markers = markers.data();
  v.d_markers = d_markers.data();
  return v;
}

nb::tuple pose_frames(const mocapgraph::BodyKernel& body, const InF& root, const InF& pose, bool jacobians) {
  const std::size_t J = body.num_joints(), K = body.num_keypoints(), P = body.num_params();
  check_shape(root, "root", {kAny, 4, 4});
  const std::size_t T = root.shape(0);
  check_shape(pose, "pose", {static_cast<std::int64_t>(T), static_cast<std::int64_t>(J - 1), 3});

  Buffer<double> joints({T, J, 3}), keypoints({T, K, 3}), rotations({T, J, 3, 3});
  std::unique_ptr<Buffer<double>> d_joints, d_keypoints;
  if (jacobians) {
    d_joints = std::make_unique<Buffer<double>>(std::vector<std::size_t>{T, J, 3, P});
    d_keypoints = std::make_unique<Buffer<double>>(std::vector<std::size_t>{T, K, 3, P});
  }
  mocapgraph::FrameOutputs out;
  out.joints = joints.get();
  out.keypoints = keypoints.get();
  out.rotations = rotations.get();
  out.d_joints = jacobians ? d_joints->get() : nullptr;
  out.d_keypoints = jacobians ? d_keypoints->get() : nullptr;
  {
    nb::gil_scoped_release release;
    body.pose_frames(T, root.data(), pose.data(), out);
  }
  return nb::make_tuple(joints.to_numpy(), keypoints.to_numpy(), rotations.to_numpy(),
                        jacobians ? d_joints->to_numpy() : nb::none(),
                        jacobians ? d_keypoints->to_numpy() : nb::none());
}

nb::tuple fk(const InI& parents, const InF& offsets, const InF& d_offsets, const InF& weights,
             const InF& markers, const InF& d_markers, const InF& root, const InF& pose, bool jacobians) {
  const mocapgraph::BodyKernel body(table_view(parents, offsets, d_offsets, weights, markers, d_markers));
  return pose_frames(body, root, pose, jacobians);
}

// Checks one frame's reprojection inputs against the body (K keypoints, J joints) and returns
// the kernel's view of them; C is the number of cameras.
mocapgraph::ReprojectionInputs frame_inputs(const mocapgraph::BodyKernel& body, const InF& root, const InF& pose,
                                            const InF& cameras, const InF& intrinsics, const InF& observed,
                                            const InF& obs_weights, double gm_sigma_px, double min_depth) {
  const std::int64_t J = static_cast<std::int64_t>(body.num_joints());
  const std::int64_t K = static_cast<std::int64_t>(body.num_keypoints());
  check_shape(root, "root", {4, 4});
  check_shape(pose, "pose", {J - 1, 3});
  check_shape(cameras, "cameras", {kAny, 4, 4});
  const std::int64_t C = static_cast<std::int64_t>(cameras.shape(0));
  check_shape(intrinsics, "intrinsics", {C, 4});
  check_shape(observed, "observed", {C, K, 2});
  check_shape(obs_weights, "obs_weights", {C, K});
  check_rotations(root.data(), 1, "root", false);
  check_rotations(cameras.data(), static_cast<std::size_t>(C), "cameras", true);
  for (std::int64_t c = 0; c < C; ++c) {
    const double* f = intrinsics.data() + 4 * c;
    if (!(f[0] > 0.0 && f[1] > 0.0 && std::isfinite(f[0]) && std::isfinite(f[1]) && std::isfinite(f[2]) &&
          std::isfinite(f[3])))
      throw std::invalid_argument("intrinsics: camera " + std::to_string(c) +
                                  " needs finite fx, fy, cx, cy with fx, fy > 0");
  }
  for (std::int64_t i = 0; i < 2 * C * K; ++i)
    if (std::isinf(observed.data()[i]))
      throw std::invalid_argument("observed: contains inf (mark missing detections with NaN)");
  if (std::isnan(gm_sigma_px)) throw std::invalid_argument("gm_sigma_px: must not be NaN");
  if (!(min_depth > 0.0) || !std::isfinite(min_depth))
    throw std::invalid_argument("min_depth: must be a finite positive depth in metres");
  for (std::int64_t i = 0; i < C * K; ++i)
    if (!(obs_weights.data()[i] >= 0.0) || std::isinf(obs_weights.data()[i]))
      throw std::invalid_argument("obs_weights: must be finite and >= 0 (camera " + std::to_string(i / K) +
                                  ", keypoint " + std::to_string(i % K) + ")");
  mocapgraph::ReprojectionInputs in;
  in.root = root.data();
  in.pose = pose.data();
  in.num_cameras = static_cast<std::size_t>(C);
  in.cameras = cameras.data();
  in.intrinsics = intrinsics.data();
  in.observed = observed.data();
  in.obs_weights = obs_weights.data();
  in.gm_sigma_px = gm_sigma_px;
  in.min_depth = min_depth;
  return in;
}

nb::tuple reproject(const InI& parents, const InF& offsets, const InF& d_offsets, const InF& weights,
                    const InF& markers, const InF& d_markers, const InF& root, const InF& pose,
                    const InF& cameras, const InF& intrinsics, const InF& observed, const InF& obs_weights,
                    double gm_sigma_px, double min_depth, bool jacobians) {
  const mocapgraph::BodyKernel body(table_view(parents, offsets, d_offsets, weights, markers, d_markers));
  const mocapgraph::ReprojectionInputs in =
      frame_inputs(body, root, pose, cameras, intrinsics, observed, obs_weights, gm_sigma_px, min_depth);
  const std::size_t C = in.num_cameras, K = body.num_keypoints();
  const std::size_t rows = 2 * C * K;
  const std::size_t cols = body.num_params() + 6 * C;
  Buffer<double> residual({rows});
  Buffer<bool> valid({C, K});
  std::unique_ptr<Buffer<double>> jacobian;
  if (jacobians) jacobian = std::make_unique<Buffer<double>>(std::vector<std::size_t>{rows, cols});

  mocapgraph::ReprojectionOutputs out;
  out.residual = residual.get();
  out.jacobian = jacobians ? jacobian->get() : nullptr;
  out.valid = valid.get();
  {
    nb::gil_scoped_release release;
    mocapgraph::reproject_frame(body, in, out);
  }
  return nb::make_tuple(residual.to_numpy(), jacobians ? jacobian->to_numpy() : nb::none(), valid.to_numpy());
}

using InB = nb::ndarray<const bool, nb::c_contig, nb::device::cpu>;

// A body table checked and prepared once (the kernel's sparsity scan), for the many calls of
// one shape: the reprojection factor's evaluations and the per-state kinematics of the body
// factors. It keeps its arrays alive.
class Body {
 public:
  Body(const InI& parents, const InF& offsets, const InF& d_offsets, const InF& weights, const InF& markers,
       const InF& d_markers)
      : parents_(parents), offsets_(offsets), d_offsets_(d_offsets), weights_(weights), markers_(markers),
        d_markers_(d_markers),
        kernel_(table_view(parents_, offsets_, d_offsets_, weights_, markers_, d_markers_)) {}

  nb::tuple fk(const InF& root, const InF& pose, bool jacobians) const {
    return pose_frames(kernel_, root, pose, jacobians);
  }

  nb::tuple reproject_factor(const InF& root, const InF& pose, const InF& cameras, const InF& intrinsics,
                             const InF& observed, const InF& obs_weights, const InF& mapped, double gm_sigma_px,
                             double min_depth, bool jacobians, const InI& permutations, const InB& allowed,
                             double relabel_cost, bool relabel, bool cost_row, const InI& focal_columns,
                             std::size_t num_focal) const {
    mocapgraph::FactorInputs in;
    in.frame = frame_inputs(kernel_, root, pose, cameras, intrinsics, observed, obs_weights, gm_sigma_px, min_depth);
    const std::size_t C = in.frame.num_cameras, K = kernel_.num_keypoints();
    const std::int64_t Ci = static_cast<std::int64_t>(C), Ki = static_cast<std::int64_t>(K);
    check_shape(mapped, "mapped", {Ki});
    for (std::size_t k = 0; k < K; ++k)
      if (!std::isfinite(mapped.data()[k])) throw std::invalid_argument("mapped: must be finite");
    if (permutations.ndim() != 2 || (permutations.shape(0) > 0 && permutations.shape(1) != K))
      throw std::invalid_argument("permutations: expected shape (H, " + std::to_string(K) + ")");
    const std::size_t H = permutations.shape(0);
    for (std::size_t i = 0; i < H * K; ++i)
      if (permutations.data()[i] < 0 || permutations.data()[i] >= Ki)
        throw std::invalid_argument("permutations: entries must lie in [0, " + std::to_string(K) + ")");
    check_shape(allowed, "allowed", {Ci, static_cast<std::int64_t>(H)});
    if (!(relabel_cost >= 0.0) || !std::isfinite(relabel_cost))
      throw std::invalid_argument("relabel_cost: must be a finite number >= 0");
    check_shape(focal_columns, "focal_columns", {Ci});
    for (std::size_t c = 0; c < C; ++c)
      if (focal_columns.data()[c] < -1 || focal_columns.data()[c] >= static_cast<std::int64_t>(num_focal))
        throw std::invalid_argument("focal_columns: entries must lie in [-1, " + std::to_string(num_focal) + ")");
    in.mapped = mapped.data();
    in.num_hypotheses = H;
    in.permutations = permutations.data();
    in.allowed = allowed.data();
    in.relabel_cost = relabel_cost;
    in.relabel = relabel;
    in.cost_row = cost_row;
    in.focal_columns = focal_columns.data();
    in.num_focal = num_focal;

    const std::size_t rows = mocapgraph::factor_rows(K, in);
    const std::size_t cols = kernel_.num_params() + 6 * C + num_focal;
    Buffer<double> residual({rows});
    Buffer<std::int64_t> choice({C});
    std::unique_ptr<Buffer<double>> jacobian;
    if (jacobians) jacobian = std::make_unique<Buffer<double>>(std::vector<std::size_t>{rows, cols});
    mocapgraph::FactorOutputs out;
    out.residual = residual.get();
    out.jacobian = jacobians ? jacobian->get() : nullptr;
    out.choice = choice.get();
    mocapgraph::reproject_factor(kernel_, in, out);
    return nb::make_tuple(residual.to_numpy(), jacobians ? jacobian->to_numpy() : nb::none(), choice.to_numpy());
  }

  std::size_t num_keypoints() const { return kernel_.num_keypoints(); }
  std::size_t num_params() const { return kernel_.num_params(); }

 private:
  InI parents_;
  InF offsets_, d_offsets_, weights_, markers_, d_markers_;
  mocapgraph::BodyKernel kernel_;  // views the arrays above: declared after them
};

nb::tuple interpolate_pose(const InF& first, const InF& second, double fraction) {
  check_shape(first, "first", {4, 4});
  check_shape(second, "second", {4, 4});
  check_rotations(first.data(), 1, "first", false);
  check_rotations(second.data(), 1, "second", false);
  if (!(fraction >= 0.0 && fraction <= 1.0)) throw std::invalid_argument("fraction: must lie in [0, 1]");
  Buffer<double> out({4, 4}), d_first({6, 6}), d_second({6, 6});
  mocapgraph::interpolate_pose(first.data(), second.data(), fraction, out.get(), d_first.get(), d_second.get());
  return nb::make_tuple(out.to_numpy(), d_first.to_numpy(), d_second.to_numpy());
}

}  // namespace

NB_MODULE(_native, m) {
  m.doc() = "Native kernels of mocapgraph: body forward kinematics and multi-camera reprojection.";

  m.def("fk", &fk, "parents"_a, "offsets"_a, "d_offsets"_a, "weights"_a, "markers"_a, "d_markers"_a,
        "root"_a, "pose"_a, "jacobians"_a,
        "Forward kinematics of T frames: root (T, 4, 4) world_T_root, pose (T, J-1, 3) axis-angle.\n\n"
        "Returns (joints (T, J, 3), keypoints (T, K, 3), rotations (T, J, 3, 3),\n"
        "d_joints (T, J, 3, P) or None, d_keypoints (T, K, 3, P) or None), P = 6 + 3 (J-1) + S;\n"
        "columns as in mocapgraph.body.kinematics.");

  m.def("reproject", &reproject, "parents"_a, "offsets"_a, "d_offsets"_a, "weights"_a, "markers"_a,
        "d_markers"_a, "root"_a, "pose"_a, "cameras"_a, "intrinsics"_a, "observed"_a, "obs_weights"_a,
        "gm_sigma_px"_a, "min_depth"_a, "jacobians"_a,
        "Geman-McClure weighted reprojection residual of one frame into C cameras.\n\n"
        "root (4, 4) world_T_root, pose (J-1, 3), cameras (C, 4, 4) world_T_camera (OpenCV axes),\n"
        "intrinsics (C, 4) fx, fy, cx, cy, observed (C, K, 2) pixels (NaN = missing), obs_weights (C, K).\n"
        "Returns (residual (2 C K,), jacobian (2 C K, P + 6 C) or None, valid (C, K) bool);\n"
        "see mocapgraph.factors.reprojection_kernel for the layout.");

  nb::class_<Body>(m, "Body",
                   "A body table (the six arrays of mocapgraph.body.native.table_arrays) checked and\n"
                   "prepared once for many evaluations; it keeps the arrays alive.")
      .def(nb::init<const InI&, const InF&, const InF&, const InF&, const InF&, const InF&>(), "parents"_a,
           "offsets"_a, "d_offsets"_a, "weights"_a, "markers"_a, "d_markers"_a)
      .def_prop_ro("num_keypoints", &Body::num_keypoints)
      .def_prop_ro("num_params", &Body::num_params, "P = 6 + 3 (J-1) + S body Jacobian columns")
      .def("fk", &Body::fk, "root"_a, "pose"_a, "jacobians"_a, "As the module's fk, on this body.")
      .def("reproject_factor", &Body::reproject_factor, "root"_a, "pose"_a, "cameras"_a, "intrinsics"_a,
           "observed"_a, "obs_weights"_a, "mapped"_a, "gm_sigma_px"_a, "min_depth"_a, "jacobians"_a,
           "permutations"_a, "allowed"_a, "relabel_cost"_a, "relabel"_a, "cost_row"_a, "focal_columns"_a,
           "num_focal"_a,
           "The reprojection factor's residual in one pass: per camera the labelling hypothesis of\n"
           "least robust cost (when relabel, under a finite gm_sigma_px), then two rows per usable\n"
           "detection (finite, obs_weights > 0), camera-major in body point order, and with cost_row the\n"
           "relabellings' cost. Body point k of camera c reads detection permutations[h, k] with weight\n"
           "obs_weights[c, permutations[h, k]] * mapped[k]. permutations (H, K) int64 (H = 0: as detected),\n"
           "allowed (C, H) bool, focal_columns (C,) int64 (-1: none).\n"
           "Returns (residual (R,), jacobian (R, P + 6 C + num_focal) or None, choice (C,) int64);\n"
           "column P + 6 C + focal_columns[c] is dr/ds of camera c's focal log scale s.");

  m.def("interpolate_pose", &interpolate_pose, "first"_a, "second"_a, "fraction"_a,
        "The pose a fraction of the way from first to second (4, 4) world_T_root: slerp of the\n"
        "rotation, linear translation. Returns (pose (4, 4), d_first (6, 6), d_second (6, 6)),\n"
        "Jacobians in GTSAM's Pose3 tangent (rotation first); see mocapgraph.factors.interpolation.");
}
