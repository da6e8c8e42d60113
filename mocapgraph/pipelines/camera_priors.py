"""Camera pose priors of a capture from its vehicles' sensors.

For every camera with what it takes, its sensor logs, mount and frame times go to the
navigation graph (:mod:`mocapgraph.graphs.navigation`); the others get a note saying why not.
``docs/vehicle-fusion.md`` describes the graph and its accuracy.
"""

from __future__ import annotations

from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.navigation import FusionNoise
from mocapgraph.graphs.navigation import OnlineNoise, VehicleTrack, fuse_vehicle, online_track

SOURCES = ("fused", "online")


def camera_priors(
    capture: Capture,
    source: str = "fused",
    *,
    nav_rate_hz: float = 10.0,
    noise: FusionNoise = FusionNoise(),
    online_noise: OnlineNoise = OnlineNoise(),
) -> tuple[dict[str, VehicleTrack], list[str]]:
    """Camera pose priors from the vehicles' sensors, for every camera that has what it takes.

    ``source="fused"`` runs :func:`~mocapgraph.graphs.navigation.fuse_vehicle` (needs a mount,
    an IMU and a GPS log); ``source="online"`` runs :func:`~mocapgraph.graphs.navigation.online_track`
    (needs a mount and a self_pose log). A camera that cannot have a track is skipped, with the
    reason in the returned notes.

    Returns:
        ``(tracks by camera name, notes)``.
    """
    if source not in SOURCES:
        raise MocapgraphError(f"unknown camera prior source {source!r}; choose one of {', '.join(SOURCES)}")
    tracks: dict[str, VehicleTrack] = {}
    notes: list[str] = []
    needs = ("imu", "gps") if source == "fused" else ("self_pose",)
    for cam in capture.cameras:
        missing = [k for k in needs if k not in cam.sensors]
        if not cam.sensors:
            notes.append(f"camera {cam.name}: skipped, no sensor logs")
            continue
        if missing:
            notes.append(f"camera {cam.name}: skipped, no {' and no '.join(missing)} log for the {source} track")
            continue
        if cam.mount is None:
            notes.append(f"camera {cam.name}: skipped, no mount (vehicle_T_camera)")
            continue
        try:
            if source == "fused":
                tracks[cam.name] = fuse_vehicle(cam.sensors, cam.mount, cam.timestamps, cam.name, nav_rate_hz=nav_rate_hz, noise=noise)
            else:
                tracks[cam.name] = online_track(cam.sensors, cam.mount, cam.timestamps, cam.name, noise=online_noise)
        except MocapgraphError as exc:
            notes.append(f"camera {cam.name}: skipped, {exc}")
    return tracks, notes
