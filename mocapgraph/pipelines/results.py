"""A solved state model written as a result: body states, camera tracks, per-state flags."""

from __future__ import annotations

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import CameraTrack, Result
from mocapgraph.graphs.state_model import Estimate, StateModel


def estimate_result(
    pipeline: str,
    capture: Capture,
    model: StateModel,
    body: BodyModel,
    estimate: Estimate,
    world_frame: str,
    parameters: dict,
    capture_label: str = "",
    cameras: list[int] | None = None,
    all_frames: bool = False,
) -> Result:
    """The result of a solve of ``model``.

    Args:
        cameras: indices of the cameras whose tracks to write (default: those with observations).
        all_frames: write a camera's pose at every frame of the capture (frames outside the
            states keep the estimate's initial value, e.g. a GPS/IMU prior); else only at its
            frames that belong to a body state.

    Joints and keypoints (of the first observed format) come from the body model's forward
    kinematics; ``flags`` hold each state's detection count and whether it had none.
    """
    fmt = model.formats[0]
    fk = body.forward(estimate.shape, estimate.roots, estimate.poses)
    detections = model.detections_per_state()
    result = Result(
        pipeline=pipeline, capture=capture_label or str(capture.path or capture.name), world_frame=world_frame,
        timestamps=model.times, joints=fk.joints, body_model=body.name, root=estimate.roots, pose=estimate.poses,
        shape=estimate.shape, keypoints=body.forward(estimate.shape, estimate.roots, estimate.poses, keypoints=fmt).keypoints,
        keypoint_format=fmt, flags={"num_detections": detections, "unconstrained": detections == 0},
        log=list(estimate.log), parameters=parameters,
    )  # fmt: skip
    for c in model.observed_cameras() if cameras is None else cameras:
        cam = capture.cameras[c]
        frames = np.arange(cam.num_frames) if all_frames else model.camera_frames(c)
        if len(frames):
            result.cameras[cam.name] = CameraTrack(cam.timestamps[frames], estimate.cameras[c][frames])
    return result
