"""Multi-view fusion regressor: body and camera-relative root poses from 2D keypoints alone.

An AirPose-like network (Saini et al., IJCV 2022) reduced to keypoints: no images, so it is small
and runs on a CPU. It initialises the ``airpose`` pipeline, where cameras are uncalibrated and
carry no sensors: each view's estimate of the root in its own camera frame, composed across two
views, gives the relative pose of the cameras.

**Input per view and frame.** The 17 COCO keypoints, picked by name from any registered format,
undistorted pixels and confidence, NaN where missing. They are normalised to the person's crop:
the box of the present points, centre ``c`` and scale ``s`` = 1.2 × its longer side, keypoints
``(uv − c)/s`` (0 where missing) with their confidence and a presence mask. The crop parameters
``P = ((c_x − p_x)/f_x, (c_y − p_y)/f_y, log(s/f_x))`` (``p`` the principal point) say where the
crop sits in the camera's field of view and how large it is there: they carry the perspective and
the distance that the normalised keypoints have lost (AirPose's "P"; the log makes the depth a
linear function of it).

**Estimate per view** (``ESTIMATE = 141`` numbers): the root's orientation in the camera frame
(6D, Zhou et al. 2019), the 21 local joint rotations (6D each, 126), the shape normalised to
``[0, 1]`` within the body's bounds (6), and the root's position in the camera frame as
``(x/z, y/z, log z)``, which the crop parameters predict almost linearly.

**Network.** Iterative error feedback (HMR, Kanazawa et al. 2018): one MLP, shared by the three
stages, maps ``[view features, current estimate, exchanged information]`` to a correction of the
estimate, starting from a learned mean. Between stages every view receives the mean over the
*other valid* views of their view-independent part — articulated pose and shape (132 numbers)
— and a flag that says whether there was any other valid view. With one view (or no other valid
view) the exchanged vector and the flag are zero, so a single view is the network's own
monocular case, seen in training.

Variants (the AirPose ablation): ``full``; ``no_exchange`` (the exchanged vector is always zero);
``no_crop`` (the crop parameters are zero in the input).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from mocapgraph.body.keypoint_formats import COCO17
from mocapgraph.body.rotations import matrix_to_rotvec
from mocapgraph.errors import MocapgraphError
from mocapgraph.priors.model_file import load_weights, read_model_file, weight_arrays, write_model_file
from mocapgraph.priors.pose_vae import _mlp, sixd_to_rotmat
from mocapgraph.priors.views import MIN_POINTS, ViewEstimate, ViewInput, coco_keypoints

FORMAT_VERSION = 1
_KEYS = ("format_version", "body_model", "variant", "shape_bounds", "config", "info")
VARIANTS = ("full", "no_exchange", "no_crop")
DATA_DIR = Path(__file__).parent / "data"

POINTS = len(COCO17)
FEATURES = 4 * POINTS + 3
"""Per view and frame: normalised ``u, v`` (34), confidence (17), presence (17), crop parameters (3)."""
CROP = slice(4 * POINTS, FEATURES)
ROOT, POSE, SHAPE, TRANSL = slice(0, 6), slice(6, 132), slice(132, 138), slice(138, 141)
ESTIMATE = 141
EXCHANGE = 133
"""Other views' mean pose (126) and shape (6), then a flag: 1 when at least one other view is valid."""
BOX_MARGIN = 1.2


def default_path(variant: str = "full") -> Path:
    """The shipped weights of ``variant``: ``fusion_regressor.npz`` or ``fusion_regressor_<variant>.npz``."""
    if variant not in VARIANTS:
        raise MocapgraphError(f"unknown fusion regressor variant {variant!r}; known: {', '.join(VARIANTS)}")
    return DATA_DIR / ("fusion_regressor.npz" if variant == "full" else f"fusion_regressor_{variant}.npz")


def crop_features(keypoints, K) -> tuple[np.ndarray, np.ndarray]:
    """Features ``(..., FEATURES)`` and validity ``(...,)`` of COCO keypoints ``(..., 17, 3)``.

    ``K`` is ``(3, 3)`` or ``(..., 3, 3)``. A point is present when finite with confidence > 0.
    Frames with fewer than 2 present points get all-zero features (no box); frames with fewer
    than :data:`MIN_POINTS` are invalid but keep their features.
    """
    kp = np.asarray(keypoints, dtype=float)
    K = np.broadcast_to(np.asarray(K, dtype=float), kp.shape[:-2] + (3, 3))
    present = np.all(np.isfinite(kp), axis=-1) & (np.nan_to_num(kp[..., 2]) > 0)
    count = present.sum(-1)
    uv = np.where(present[..., None], kp[..., :2], 0.0)
    lo = np.where(present[..., None], uv, np.inf).min(-2)
    hi = np.where(present[..., None], uv, -np.inf).max(-2)
    boxed = count >= 2
    lo, hi = np.where(boxed[..., None], lo, 0.0), np.where(boxed[..., None], hi, 1.0)
    centre = 0.5 * (lo + hi)
    # One pixel at least, so two coincident points still give a finite crop.
    scale = np.maximum(BOX_MARGIN * (hi - lo).max(-1), 1.0)
    normalised = np.where(present[..., None], (uv - centre[..., None, :]) / scale[..., None, None], 0.0)
    crop = np.stack(
        [(centre[..., 0] - K[..., 0, 2]) / K[..., 0, 0], (centre[..., 1] - K[..., 1, 2]) / K[..., 1, 1], np.log(scale / K[..., 0, 0])],
        axis=-1,
    )  # fmt: skip
    features = np.concatenate(
        [normalised.reshape(kp.shape[:-2] + (2 * POINTS,)), np.where(present, kp[..., 2], 0.0), present.astype(float), crop], axis=-1
    )  # fmt: skip
    return np.where(boxed[..., None], features, 0.0), count >= MIN_POINTS


class FusionNet(torch.nn.Module):
    """The network of the module docstring: ``stages`` shared refinement steps from a learned mean."""

    def __init__(self, variant: str = "full", width: int = 448, stages: int = 3):
        super().__init__()
        if variant not in VARIANTS:
            raise MocapgraphError(f"unknown fusion regressor variant {variant!r}; known: {', '.join(VARIANTS)}")
        if width < 1 or stages < 1:
            raise MocapgraphError(f"FusionNet: width and stages must be >= 1, got {width}, {stages}")
        self.variant, self.width, self.stages = variant, int(width), int(stages)
        self.mean = torch.nn.Parameter(torch.zeros(ESTIMATE))
        self.regressor = _mlp(FEATURES + ESTIMATE + EXCHANGE, self.width, ESTIMATE)
        # Small last layer: each stage starts as a gentle correction of the previous estimate.
        with torch.no_grad():
            self.regressor[-1].weight.mul_(0.1)
            self.regressor[-1].bias.zero_()

    def exchange(self, estimate: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """``(B, V, EXCHANGE)``: per view, the mean pose and shape of the *other* valid views, and the flag."""
        if self.variant == "no_exchange":
            return estimate.new_zeros(estimate.shape[:2] + (EXCHANGE,))
        shared = estimate[..., POSE.start : SHAPE.stop]
        w = valid.to(estimate.dtype)[..., None]
        others = (shared * w).sum(1, keepdim=True) - shared * w
        count = w.sum(1, keepdim=True) - w
        mean = others / count.clamp(min=1.0)
        return torch.cat([mean, (count > 0).to(estimate.dtype)], dim=-1)

    def forward(self, features: torch.Tensor, valid: torch.Tensor) -> list[torch.Tensor]:
        """Estimates ``(B, V, ESTIMATE)`` after each stage, from features ``(B, V, FEATURES)`` and ``valid (B, V)``."""
        if self.variant == "no_crop":
            features = torch.cat([features[..., : CROP.start], torch.zeros_like(features[..., CROP])], dim=-1)
        estimate = self.mean.expand(features.shape[:2] + (ESTIMATE,))
        out = []
        for _ in range(self.stages):
            x = torch.cat([features, estimate, self.exchange(estimate, valid)], dim=-1)
            estimate = estimate + self.regressor(x)
            out.append(estimate)
        return out


def decode(estimate: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(..., ESTIMATE)`` → root rotation ``(..., 3, 3)`` (camera frame), joint rotations
    ``(..., 21, 3, 3)``, normalised shape ``(..., 6)`` (unclipped) and root position ``(..., 3)`` (camera frame, m)."""
    R_root = sixd_to_rotmat(estimate[..., ROOT])
    R_pose = sixd_to_rotmat(estimate[..., POSE].reshape(estimate.shape[:-1] + (21, 6)))
    t = estimate[..., TRANSL]
    z = torch.exp(t[..., 2:3])
    return R_root, R_pose, estimate[..., SHAPE], torch.cat([t[..., :2] * z, z], dim=-1)


class FusionRegressor:
    """The trained network with what it needs to read keypoints and write body estimates.

    Args:
        net: the network (its ``variant`` is the regressor's).
        shape_bounds: ``(S, 2)`` the body model's shape bounds, which the normalised shape maps onto.
        body_model: the body model the poses and shapes are in (e.g. ``"anny"``).
        info: free-form training record, saved with the file.
    """

    def __init__(self, net: FusionNet, shape_bounds, body_model: str = "anny", info: dict | None = None):
        self.net = net.eval()
        self.shape_bounds = np.asarray(shape_bounds, dtype=float)
        if self.shape_bounds.shape != (6, 2) or not np.all(self.shape_bounds[:, 1] > self.shape_bounds[:, 0]):
            raise MocapgraphError(f"FusionRegressor: shape_bounds must be (6, 2) with low < high, got {self.shape_bounds.shape}")
        self.body_model = body_model
        self.info = dict(info or {})

    @property
    def variant(self) -> str:
        return self.net.variant

    def estimate(self, features, valid) -> dict[str, np.ndarray]:
        """The last stage for features ``(N, V, FEATURES)`` and ``valid (N, V)``, decoded:
        ``camera_T_root (N, V, 4, 4)``, ``pose (N, V, 21, 3)``, ``shape (N, V, S)`` (clipped)."""
        with torch.no_grad():
            est = self.net(torch.as_tensor(features, dtype=torch.float32), torch.as_tensor(valid))[-1]
            R_root, R_pose, shape, t = (x.double().numpy() for x in decode(est))
        lo, hi = self.shape_bounds.T
        camera_T_root = np.tile(np.eye(4), R_root.shape[:-2] + (1, 1))
        camera_T_root[..., :3, :3] = R_root
        camera_T_root[..., :3, 3] = t
        return {
            "camera_T_root": camera_T_root,
            "pose": matrix_to_rotvec(R_pose),
            "shape": lo + np.clip(shape, 0.0, 1.0) * (hi - lo),
        }

    def predict(self, views: list[ViewInput], batch: int = 4096) -> list[ViewEstimate]:
        """One estimate per view for synchronised views (the same ``T``); see :class:`ViewEstimate`.

        Frames where a view is invalid still get its (flagged) estimate; the exchange between
        views uses only the valid ones.
        """
        if not views:
            raise MocapgraphError("FusionRegressor.predict: needs at least one view")
        feats, valid = [], []
        for i, view in enumerate(views):
            kp = coco_keypoints(view.keypoints, view.fmt)
            K = np.asarray(view.K, dtype=float)
            if kp.ndim != 3 or K.shape != (3, 3):
                raise MocapgraphError(f"view {i}: keypoints must be (T, F, 3) and K (3, 3), got {kp.shape} and {K.shape}")
            f, v = crop_features(kp, K)
            feats.append(f)
            valid.append(v)
        if len({len(f) for f in feats}) != 1:
            raise MocapgraphError(f"FusionRegressor.predict: views have different frame counts {[len(f) for f in feats]}")
        features, valid = np.stack(feats, axis=1), np.stack(valid, axis=1)
        parts = [self.estimate(features[i : i + batch], valid[i : i + batch]) for i in range(0, max(1, len(features)), batch)]
        out = {k: np.concatenate([p[k] for p in parts]) for k in ("camera_T_root", "pose", "shape")}
        return [
            ViewEstimate(out["camera_T_root"][:, v], out["pose"][:, v], out["shape"][:, v], valid[:, v].copy())
            for v in range(len(views))
        ]

    def save(self, path: str | Path) -> Path:
        """Write one ``.npz`` (no pickle): version, body model, variant, shape bounds, config and
        info as JSON, and the float32 weights as ``state/<name>``; atomic rename."""
        return write_model_file(
            path, format_version=FORMAT_VERSION, body_model=self.body_model, variant=self.variant,
            shape_bounds=self.shape_bounds, config=json.dumps({"width": self.net.width, "stages": self.net.stages}),
            info=json.dumps(self.info), **weight_arrays(self.net, np.float32),
        )  # fmt: skip

    @classmethod
    def load(cls, path: str | Path) -> FusionRegressor:
        """Read a file written by :meth:`save`; every error is a MocapgraphError naming the file."""
        d = read_model_file(path, "fusion regressor", _KEYS, FORMAT_VERSION)
        try:
            config = json.loads(str(d["config"]))
            net = FusionNet(str(d["variant"]), width=config["width"], stages=config["stages"])
            regressor = cls(net, d["shape_bounds"], body_model=str(d["body_model"]), info=json.loads(str(d["info"])))
        except (MocapgraphError, ValueError) as exc:
            raise MocapgraphError(f"{path}: {exc}") from None
        except KeyError as exc:
            raise MocapgraphError(f"{path}: config has no {exc.args[0]!r}") from None
        load_weights(path, net, d)
        return regressor


def load_default_fusion_regressor(variant: str = "full") -> FusionRegressor:
    """The shipped weights of ``variant`` (``full``, ``no_exchange``, ``no_crop``); a missing or
    corrupt file is a MocapgraphError naming it."""
    return FusionRegressor.load(default_path(variant))
