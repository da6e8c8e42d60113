"""A capture turned into the graphs' state model: the one road from loaded keypoints to factors.

Every pipeline calls :func:`capture_state_model`; the keypoints are undistorted once, inside
:func:`~mocapgraph.graphs.state_model.build_state_model`.
"""

from __future__ import annotations

import numpy as np

from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.camera_imu import CameraImu
from mocapgraph.graphs.state_model import CameraDetections, CameraInfo, StateModel, build_state_model


def detector_names(capture: Capture, detectors: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The detectors to use: ``detectors`` or every detector of any camera, in order of first
    appearance; a MocapgraphError when there are none."""
    names = tuple(detectors) if detectors else tuple(dict.fromkeys(n for cam in capture.cameras for n in cam.detectors))
    if not names:
        raise MocapgraphError(f"capture {capture.name!r}: no camera has detections")
    return names


def camera_infos(capture: Capture) -> list[CameraInfo]:
    """The cameras as the graphs see them; a camera's focal length is a guess when the capture's
    import said so (``metadata.imported.guessed_intrinsics``)."""
    guessed = set(capture.metadata.get("imported", {}).get("guessed_intrinsics", []))
    return [
        CameraInfo(cam.name, np.asarray(cam.K, dtype=float), cam.moving, cam.timestamps, cam.frame_rate, cam.name in guessed) for cam in capture.cameras
    ]


def capture_state_model(
    capture: Capture,
    sync: str,
    *,
    detectors: tuple[str, ...] | None = None,
    cameras: set[str] | None = None,
    gates: dict[tuple[str, str], np.ndarray] | None = None,
    reference: int = 0,
    rate_hz: float = 30.0,
) -> StateModel:
    """The capture's detections as a :class:`~mocapgraph.graphs.state_model.StateModel`.

    Args:
        sync: ``"grid"``, ``"states"`` or ``"closest"`` (:mod:`mocapgraph.graphs.sync`).
        detectors: which detectors (default all).
        cameras: names of the cameras whose detections are used (default all); the others
            still place states in time.
        gates: ``{(camera, detector): (F,) or (F, K)}`` multipliers of the confidences.
        reference: the camera whose frames are the states under ``"closest"``.
        rate_hz: the state rate under ``"grid"``.
    """
    names = detector_names(capture, detectors)
    gates = gates or {}
    found = []
    for c, cam in enumerate(capture.cameras):
        if cameras is not None and cam.name not in cameras:
            continue
        for name in names:
            det = cam.detectors.get(name)
            if det is not None:
                found.append(CameraDetections(c, name, det.format, det.keypoints, cam.distortion, gates.get((cam.name, name))))
    return build_state_model(camera_infos(capture), found, sync, reference=reference, rate_hz=rate_hz)


def camera_imus(capture: Capture) -> tuple[dict[int, CameraImu], list[str]]:
    """The IMU log of every moving camera that has one and a mount placing the camera on it
    (index → :class:`~mocapgraph.graphs.camera_imu.CameraImu`), and notes on the logs not used."""
    out, notes = {}, []
    for c, cam in enumerate(capture.cameras):
        if "imu" not in cam.sensors:
            continue
        if not cam.moving:
            notes.append(f"camera {cam.name}: static, its IMU log not used")
        elif cam.mount is None:
            notes.append(f"camera {cam.name}: IMU log not used, no mount places the camera on the IMU")
        else:
            out[c] = CameraImu.from_log(cam.sensors["imu"], cam.mount, cam.name)
    return out, notes
