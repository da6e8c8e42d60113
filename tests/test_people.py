"""People in one camera over time (``track_people``) and the person to fit across cameras
(``select_person``, ``write_person_capture``), against synthetic truth."""

from __future__ import annotations

import numpy as np
import pytest
from people_scene import SWAP, make_scene

from mocapgraph.data_tools.io.capture import load_capture
from mocapgraph.data_tools.tracking.people import (
    PersonTracks,
    choose_person,
    keypoint_box,
    parse_person,
    pose_distance,
    select_person,
    track_people,
    write_person_capture,
)
from mocapgraph.errors import MocapgraphError

HEIGHT = 300.0


def template(seed: int) -> np.ndarray:
    """``(33, 2)`` a 'person' 300 px tall and 120 px wide, feet at y = 0 (pixels, y down: negative)."""
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-60, 60, 33), -np.linspace(0, HEIGHT, 33)], axis=1)


def detection(shape: np.ndarray, x: float, y: float, identity: int, rng) -> np.ndarray:
    """A detection of person ``identity`` (its confidence 0.9 - 0.1 identity, which the tracker
    ignores above 0.5 and the test reads back) at feet ``(x, y)``, with 1.5 px of noise."""
    kp = np.empty((33, 3))
    kp[:, :2] = shape + [x, y] + rng.normal(scale=1.5, size=(33, 2))
    kp[:, 2] = 0.9 - 0.1 * identity
    return kp


def identities(tracks: PersonTracks) -> list[np.ndarray]:
    """Per track, the identities of its detections (from their confidences)."""
    out = []
    for track in tracks.keypoints:
        conf = track[tracks.seen[len(out)], 0, 2]
        out.append(np.round((0.9 - conf) / 0.1).astype(int))
    return out


def test_box_and_distance():
    kp = np.zeros((33, 3))
    kp[:, :2] = np.stack([np.linspace(10, 50, 33), np.linspace(100, 400, 33)], axis=1)
    kp[:, 2] = 0.9
    kp[0] = [5000.0, 5000.0, 0.3]  # a guess: not in the box
    kp[1] = np.nan
    np.testing.assert_allclose(keypoint_box(kp), [kp[2:, 0].min(), kp[2:, 1].min(), 50, 400, 0.9])
    np.testing.assert_allclose(keypoint_box(kp, size=(40, 300)), [kp[2:, 0].min(), kp[2:, 1].min(), 39, 299, 0.9])
    assert np.isnan(keypoint_box(np.full((33, 3), np.nan))).all()
    assert keypoint_box(np.stack([kp, kp])).shape == (2, 5)
    moved = kp.copy()
    moved[:, 0] += 30.0  # 30 px on a person whose seen points span 300 px - (a fraction)
    span = np.ptp(kp[2:, 1])
    assert pose_distance(kp, moved) == pytest.approx(30.0 / span)
    assert pose_distance(kp, kp) == 0.0
    few = kp.copy()
    few[3:, :] = np.nan
    assert pose_distance(kp, few) == np.inf  # only 2 points seen by both


def test_two_people_crossing_with_dropouts_and_a_sustained_swap():
    """Two people of the same build walk towards each other and cross (x 100 → 690 and 690 → 100
    over 60 frames, meeting at frame 29.5); B is hidden for frames 26-33 around the crossing; 10 %
    of all detections are missed; A's labels are swapped for frames 40-50; a spurious detection
    appears for 2 frames; the detections come in a random order."""
    rng = np.random.default_rng(7)
    shape = template(0)
    frames = []
    for t in range(60):
        people = [detection(shape, 100 + 10 * t, 600, 0, rng), detection(shape, 690 - 10 * t, 600, 1, rng)]
        if 40 <= t <= 50:
            people[0] = people[0][SWAP]
        if 26 <= t <= 33:
            people.pop(1)
        people = [p for p in people if rng.random() > 0.1]
        if t in (15, 16):
            people.append(detection(template(5), 1500, 200, 2, rng))
        frames.append(np.array([people[i] for i in rng.permutation(len(people))]).reshape(-1, 33, 3))
    tracks = track_people(frames)
    assert tracks.num_tracks == 2 and tracks.keypoints.shape == (2, 60, 33, 3)
    found = identities(tracks)
    # every detection of the two people is in a track, and every track holds one person only
    assert sorted(len(f) for f in found) == sorted(int(sum((f[:, 0, 2] == 0.9 - 0.1 * i).sum() for f in frames)) for i in (0, 1))
    assert [set(f.tolist()) for f in found] == [{0}, {1}]  # A starts first: track 0
    # the swapped frames stay in A's track, as detected (the tracker does not relabel)
    a = tracks.keypoints[0]
    for t in range(40, 51):
        if tracks.seen[0, t]:
            assert abs(a[t, 0, 0] - (100 + 10 * t + shape[SWAP[0], 0])) < 10


def test_tracks_start_end_and_gaps():
    """A is seen from frame 0 to 19, then a new person at A's last place from frame 55 (a gap
    longer than max_gap=30: a new track); B from 5 to 59 with a 20-frame gap (within max_gap:
    continued); C enters at frame 40."""
    rng = np.random.default_rng(3)
    frames = []
    for t in range(60):
        people = []
        if t < 20:
            people.append(detection(template(0), 100 + 5 * t, 500, 0, rng))
        if t >= 55:
            people.append(detection(template(0), 195, 500, 3, rng))
        if 5 <= t < 25 or 45 <= t:
            people.append(detection(template(1), 700, 500 + 0.5 * t, 1, rng))
        if t >= 40:
            people.append(detection(template(2), 1200 - 3 * t, 550, 2, rng))
        frames.append(people)
    tracks = track_people(frames, max_gap=30)
    assert tracks.num_tracks == 4
    assert [set(f.tolist()) for f in identities(tracks)] == [{0}, {1}, {2}, {3}]
    np.testing.assert_array_equal(tracks.seen.sum(axis=1), [20, 35, 20, 5])
    # with a shorter memory B's gap splits it; with min_frames=6 the newcomer of 5 frames is dropped
    assert [set(f.tolist()) for f in identities(track_people(frames, max_gap=10, min_frames=6))] == [{0}, {1}, {2}, {1}]


def test_track_people_errors():
    with pytest.raises(MocapgraphError, match=r"frame 1: detections must be \(N, 33, 3\)"):
        track_people([np.zeros((0, 33, 3)), np.zeros((1, 17, 3))])
    with pytest.raises(MocapgraphError, match="max_gap"):
        track_people([], max_gap=0)
    assert track_people([np.zeros((0, 33, 3))] * 3).keypoints.shape == (0, 3, 33, 3)


def scene_tracks(scene) -> dict[str, PersonTracks]:
    return {c: PersonTracks(t) for c, t in scene.tracks.items()}


def test_select_person_by_rule_and_rank():
    scene = make_scene(seed=1)
    tracks = scene_tracks(scene)
    sizes = {c: scene.size for c in tracks}
    K = {c: scene.K for c in tracks}
    # truth: how tall and how central each person is, averaged over the cameras (as PersonSummary)
    height, offset = np.zeros(2), np.zeros(2)
    w, h = scene.size
    for cam, kp in scene.tracks.items():
        for i, person in enumerate(scene.truth[cam]):
            box = keypoint_box(kp[i], scene.size)
            box = box[np.isfinite(box[:, 0])]
            height[person] += np.median(box[:, 3] - box[:, 1]) / h / len(tracks)
            centre = 0.5 * (box[:, :2] + box[:, 2:4]) - [w / 2, h / 2]
            offset[person] += np.median(np.linalg.norm(centre, axis=1)) / (0.5 * np.hypot(w, h)) / len(tracks)
    largest = select_person(tracks, sizes, K)
    association = largest.association
    assert largest.rule == "largest" and largest.chosen == 0 and len(largest.people) == 2
    for rank, p in enumerate(largest.people):
        person = scene.truth["cam1"][p.tracks["cam1"][0]]
        assert {c: scene.truth[c][t[0]] for c, t in p.tracks.items()} == {c: person for c in tracks}
        assert p.height == pytest.approx(height[person], rel=1e-9) and p.offset == pytest.approx(offset[person], rel=1e-9)
        assert p.frames == {c: int(np.isfinite(scene.tracks[c][t[0], :, :, 2]).any(-1).sum()) for c, t in p.tracks.items()}
        assert p.affinity > 0.7
    assert largest.people[0].height > largest.people[1].height
    central = choose_person(association, tracks, sizes, person="central")
    assert central.person.offset == min(p.offset for p in central.people)
    second = choose_person(association, tracks, sizes, person="1")
    assert second.rule == "index" and second.person.tracks == largest.people[1].tracks
    for cam in tracks:
        np.testing.assert_array_equal(second.keypoints[cam], scene.tracks[cam][second.person.tracks[cam][0]])
    text = second.describe()
    assert "2 people seen; tracks per camera: cam1 2, cam2 2, cam3 2, cam4 2" in text and "fitting person 1: rank 1 as asked" in text
    meta = second.metadata()
    assert meta["people_seen"] == 2 and meta["chosen"] == 1 and meta["tracks_per_camera"] == {c: 2 for c in tracks}
    with pytest.raises(MocapgraphError, match="person 2 does not exist: 2 people were seen"):
        choose_person(association, tracks, sizes, person=2)
    with pytest.raises(MocapgraphError, match="person must be largest or central or a rank"):
        parse_person("tallest")


def _cam2_in_pieces(scene, first: np.ndarray, second: np.ndarray):
    """cam2's first track replaced by two pieces ``first`` and ``second``: asserts they join one
    person, and returns that person's rank and the choice of them."""
    tracks = scene_tracks(scene)
    tracks["cam2"] = PersonTracks(np.stack([first, scene.tracks["cam2"][1], second]))
    sizes = {c: scene.size for c in tracks}
    choice = select_person(tracks, sizes, {c: scene.K for c in tracks})
    assert {p.tracks["cam2"] for p in choice.people} == {(0, 2), (1,)}
    merged = [k for k, p in enumerate(choice.people) if p.tracks["cam2"] == (0, 2)][0]
    return merged, choose_person(choice.association, tracks, sizes, person=merged)


def test_fragments_of_one_person_in_a_camera_are_merged():
    """cam2's track of the first person is cut in two at frame 30 (as a tracker does after a long
    occlusion): both fragments join that person, and its keypoints there are whole again."""
    scene = make_scene(seed=2)
    kp = scene.tracks["cam2"]
    first, second = kp[0].copy(), kp[0].copy()
    first[30:], second[:30] = np.nan, np.nan
    merged, picked = _cam2_in_pieces(scene, first, second)
    np.testing.assert_array_equal(picked.keypoints["cam2"], kp[0])
    assert picked.people[merged].frames["cam2"] == int(np.isfinite(kp[0, :, :, 2]).any(-1).sum())


def test_a_person_split_in_two_for_a_frame_is_one_person():
    """cam2's detector splits the first person into two partial skeletons at frame 30 (upper and
    lower body), and the track restarts there: the two tracks share that frame, join that person
    all the same, and the merged keypoints keep the fuller piece there."""
    scene = make_scene(seed=2)
    kp = scene.tracks["cam2"]
    first, second = kp[0].copy(), kp[0].copy()
    first[31:], second[:30] = np.nan, np.nan
    first[30, 23:] = np.nan  # the upper body's piece
    second[30, :23] = np.nan  # the legs' piece
    merged, picked = _cam2_in_pieces(scene, first, second)
    fuller = first[30] if np.isfinite(first[30, :, 2]).sum() > np.isfinite(second[30, :, 2]).sum() else second[30]
    np.testing.assert_array_equal(picked.keypoints["cam2"][30], fuller)
    np.testing.assert_array_equal(np.delete(picked.keypoints["cam2"], 30, axis=0), np.delete(kp[0], 30, axis=0))
    assert picked.people[merged].frames["cam2"] == int(np.isfinite(kp[0, :, :, 2]).any(-1).sum())
    # sharing more frames than a split explains, they stay two people
    first[31:34] = kp[0, 31:34]
    tracks = scene_tracks(scene)
    tracks["cam2"] = PersonTracks(np.stack([first, kp[1], second]))
    choice = select_person(tracks, {c: scene.size for c in tracks}, {c: scene.K for c in tracks})
    assert (0, 2) not in {p.tracks.get("cam2") for p in choice.people}


def test_write_person_capture(tmp_path):
    scene = make_scene(seed=3)
    tracks = scene_tracks(scene)
    sizes = {c: scene.size for c in tracks}
    path, choice = write_person_capture(tracks, sizes, 20.0, tmp_path / "cap", person=1, metadata={"source": "test"})
    capture = load_capture(path)
    assert capture.metadata["source"] == "test" and capture.metadata["people"]["chosen"] == 1
    assert capture.metadata["imported"] == {"calibrated": [], "guessed_intrinsics": ["cam1", "cam2", "cam3", "cam4"]}
    for cam in capture.cameras:
        det = cam.detectors["mediapipe"]
        np.testing.assert_allclose(det.keypoints, choice.keypoints[cam.name])
        assert cam.extrinsics is None and cam.K[0, 0] == pytest.approx(1.2 * 1280)
    # a person only some cameras see is refused, naming them
    tracks["cam4"] = PersonTracks(scene.tracks["cam4"][[choice.people[0].tracks["cam4"][0]]])
    with pytest.raises(MocapgraphError, match="person 1 is not seen by camera\\(s\\) cam4"):
        write_person_capture(tracks, sizes, 20.0, tmp_path / "cap2", person=1)
