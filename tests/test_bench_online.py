"""The long online benchmark's mirrored stream: every pass gives the loop the same frames, in time order."""

import numpy as np

from mocapgraph.benchmarks.online import mirrored_stream
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.pipelines.online import stream


def test_mirrored_stream_repeats_the_frames_forwards_and_backwards():
    capture = synthesize("rich", seed=3, duration_s=1.0)
    original = list(stream(capture))
    frames = list(mirrored_stream(capture, 3))
    n = len(original)
    assert len(frames) == 3 * n
    times = np.array([f.timestamp for f in frames])
    assert (np.diff(times) >= 0).all()
    for cam in {f.camera for f in original}:
        assert (np.diff([f.timestamp for f in frames if f.camera == cam]) > 0).all()
    step = 1.0 / capture.cameras[0].frame_rate
    t0, t1 = original[0].timestamp, original[-1].timestamp
    for k in range(3):
        part = frames[k * n : (k + 1) * n]
        assert np.isclose(part[0].timestamp, t0 + k * (t1 - t0 + step)) and np.isclose(part[-1].timestamp - part[0].timestamp, t1 - t0)
        # the same detections, forwards in even passes and backwards in odd ones, at times mirrored about the pass's middle
        expected = original if k % 2 == 0 else original[::-1]
        by_camera = {}
        for f in expected:
            by_camera.setdefault(f.camera, []).append(f.keypoints)
        for cam, keypoints in by_camera.items():
            got = [f.keypoints for f in part if f.camera == cam]
            np.testing.assert_array_equal(np.stack(got), np.stack(keypoints))
        offsets = np.array([f.timestamp for f in part]) - part[0].timestamp
        source = np.array([f.timestamp - t0 for f in expected])
        np.testing.assert_allclose(np.sort(offsets), np.sort(source if k % 2 == 0 else (t1 - t0) - source), atol=1e-9)
