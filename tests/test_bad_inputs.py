"""Every crasher the format fuzzer (tests/test_fuzz_formats.py) and the adversarial review of
issue 19 found, kept as an explicit case: each ends in one error naming the file and the field
(``mocapgraph: error:``, exit 2), within bounded memory, or loads as it should."""

from __future__ import annotations

import io
import logging
import resource
import tomllib
import zipfile

import numpy as np
import pytest
import tomli_w
from format_mutations import huge_header
from test_capture import edit_manifest, make_capture

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.capture import CaptureError, load_capture, write_capture
from mocapgraph.data_tools.io.result import Result, ResultError, load_result, write_result
from mocapgraph.errors import MocapgraphError


@pytest.fixture
def unit(tmp_path):
    return write_capture(make_capture(), tmp_path / "cap")


def refused(path, match: str, load=load_capture, error=CaptureError) -> str:
    with pytest.raises(error, match=match) as info:
        load(path)
    return str(info.value)


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# --- damaged arrays -------------------------------------------------------------------------

DETECTOR = "cameras/static0/detector_openpose.npz"
TIMESTAMPS = "cameras/static0/timestamps.npy"


def _flip_crc(data: bytes) -> bytes:
    """The archive with one byte of a member's data changed (its CRC no longer matches)."""
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        info = z.infolist()[0]
    at = info.header_offset + 30 + len(info.filename) + len(info.extra) + 100
    return data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1 :]


def _encrypted(data: bytes) -> bytes:
    """The archive with its first member marked encrypted in the central directory (zipfile then
    asks for a password: a RuntimeError, which the fuzzer found)."""
    at = data.index(b"PK\x01\x02") + 8  # the member's general-purpose flags
    return data[:at] + bytes([data[at] | 0x01]) + data[at + 1 :]


@pytest.mark.parametrize(
    ("rel", "damage", "message"),
    [
        (DETECTOR, _flip_crc, r"detector_openpose.npz: not a readable .npz file \(BadZipFile: Bad CRC-32"),
        (DETECTOR, lambda d: d[: len(d) // 2], r"detector_openpose.npz: not a readable .npz file \(BadZipFile"),
        (DETECTOR, lambda d: b"", r"detector_openpose.npz: not a readable .npz file"),
        (DETECTOR, _encrypted, r"detector_openpose.npz: .*encrypted"),
        (DETECTOR, lambda d: np.lib.format.magic(1, 0), r"detector_openpose.npz: not a readable .npz file"),
        (DETECTOR, lambda d: huge_header(), r"detector_openpose.npz: not a readable .npz file"),  # an .npy where an .npz goes
        (TIMESTAMPS, lambda d: _npz_bytes(x=np.zeros(3)), r"timestamps.npy: not a readable .npy file"),  # and the reverse
        (TIMESTAMPS, lambda d: d[:60], r"timestamps.npy: not a readable .npy file"),  # header cut
        (TIMESTAMPS, lambda d: d[:-8], r"timestamps.npy: cut short or damaged \(shape \(6,\) needs 48 bytes, the file has 40\)"),
        (TIMESTAMPS, lambda d: d.replace(b"'shape': (6,)", b"'shape': (6,,)"), r"timestamps.npy: not a readable .npy file"),
        (TIMESTAMPS, lambda d: d.replace(b"'shape': (6,)", b"'shape': ((("), r"timestamps.npy: not a readable .npy file"),
        (TIMESTAMPS, lambda d: huge_header(), r"timestamps.npy: shape \(1000000000000, 22, 3\) would need 4.92e\+05 GiB"),
        (TIMESTAMPS, lambda d: huge_header((10**6,)), r"timestamps.npy: cut short or damaged \(shape \(1000000,\) needs 8000000 bytes"),
    ],
)
def test_damaged_arrays_are_refused_before_anything_is_allocated(unit, rel, damage, message):
    file = unit / rel
    file.write_bytes(damage(file.read_bytes()))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    refused(unit, message)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 100 * 1024  # KiB: no terabyte request was tried


def test_an_npz_member_claiming_a_huge_shape_is_refused(unit):
    with zipfile.ZipFile(unit / DETECTOR, "w") as z:
        z.writestr("keypoints.npy", huge_header())
    refused(unit, r"detector_openpose.npz: keypoints: shape \(1000000000000, 22, 3\) would need")


@pytest.mark.parametrize(
    ("values", "message"),
    [
        (np.arange(6).astype("datetime64[s]"), r"timestamps.npy: holds datetime64\[s\] values; expected numbers"),
        (np.array([(t, 0) for t in range(6)], dtype=[("t", "f8"), ("i", "i4")]), r"timestamps.npy: holds .* values; expected numbers"),
        (np.arange(6) * (1 + 1j), r"timestamps.npy: holds complex128 values"),
        (np.array(["0", "1"]), r"timestamps.npy: holds <U1 values"),
        (np.ones(6, dtype=bool), r"timestamps: expected numbers, got bool values"),
    ],
)
def test_timestamps_that_are_not_seconds_are_refused(unit, values, message):
    np.save(unit / TIMESTAMPS, values)
    refused(unit, message)


def test_a_pickled_array_is_refused(unit):
    np.save(unit / TIMESTAMPS, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    refused(unit, r"timestamps.npy: holds object values")


# --- text: nesting, encodings, NUL bytes --------------------------------------------------------


def test_deeply_nested_toml_is_refused(unit):
    (unit / "capture.toml").write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    refused(unit, r"capture.toml: not valid TOML \(nested too deeply\)")


def test_a_manifest_that_is_not_utf8_or_holds_nul_is_refused(unit):
    text = (unit / "capture.toml").read_bytes()
    (unit / "capture.toml").write_bytes(text.replace(b"unit", b"unit\xe9", 1))
    refused(unit, r"capture.toml: not a TOML manifest \(byte \d+ is not UTF-8\)")
    (unit / "capture.toml").write_bytes(text.replace(b"unit", b"un\0it", 1))
    refused(unit, r"capture.toml: not a TOML manifest \(it holds NUL bytes\)")


def _result(tmp_path, log=None):
    T = 4
    result = Result(
        pipeline="baseline", capture="nowhere", world_frame="capture", timestamps=np.arange(T) / 30.0,
        joints=np.zeros((T, 22, 3)), log=log or [{"iteration": 0, "cost": 1.0}], parameters={"seed": 0},
    )  # fmt: skip
    return write_result(result, tmp_path / "res")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"[" * 100000 + b"]" * 100000, r"log.json: not valid JSON \(nested too deeply\)"),
        (b'[{"iteration": 0, "cost": "\xff"}]', r"log.json: not a UTF-8 JSON file \(byte 27 is not UTF-8\)"),
        (b'{"iteration": 0}', r"log.json: expected a list of objects"),
        (b"[1, 2]", r"log.json: expected a list of objects"),
    ],
)
def test_a_bad_solve_log_is_refused(tmp_path, content, message):
    res = _result(tmp_path)
    (res / "log.json").write_bytes(content)
    refused(res, message, load_result, ResultError)


# --- types where tables, lists and numbers go ---------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("detectors = [", "detectors = 5\nformer = [", r"cameras.static0.detectors: expected a list of tables \(\[\[detectors\]\]\), got int"),
        ("sensors = [", "sensors = 5\nformer = [", r"cameras.static0.sensors: expected a list of tables"),
        ("frame_rate = 30.0", "frame_rate = nan", r"cameras.static0.frame_rate: must be finite, got nan"),
        ("frame_rate = 30.0", "frame_rate = inf", r"cameras.static0.frame_rate: must be finite, got inf"),
        ("frame_rate = 30.0", "frame_rate = true", r"cameras.static0.frame_rate: expected a number, got bool True"),
        ("frame_rate = 30.0", "frame_rate = 1e9", r"cameras.static0.frame_rate: 1e\+09 is outside \(0, 10000\] fps"),
        ("version = 1", "version = true", r"capture.toml: version: this mocapgraph reads version 1 \(an integer\), the file says True"),
        ("version = 1", "version = 1.0", r"capture.toml: version: this mocapgraph reads version 1 \(an integer\), the file says 1.0"),
        ("moving = false", "moving = 0", r"cameras.static0.moving: expected bool, got int"),
        ("-0.05,", "1e10,", r"cameras.static0.distortion: 1e\+10 is outside \[-1000, 1000\]"),
        ("1000.0,", "1e300,", r"cameras.static0.K: 1e\+300 is outside \[-1e\+06, 1e\+06\] px"),
    ],
)
def test_wrong_types_and_values_in_the_manifest_are_refused(unit, old, new, message):
    edit_manifest(unit, old, new)
    refused(unit, message)


def test_booleans_are_not_pixels(unit):
    text = (unit / "capture.toml").read_text()
    start = text.index("image_size = [")
    end = text.index("]", start) + 1
    (unit / "capture.toml").write_text(text[:start] + "image_size = [true, true]" + text[end:])
    refused(unit, r"cameras.static0.image_size\[0\]: expected an integer, got bool True")


def test_result_parameters_must_be_a_table(tmp_path):
    res = _result(tmp_path)
    text = (res / "result.toml").read_text()
    (res / "result.toml").write_text(text.replace("[parameters]\nseed = 0", "parameters = 5"))
    refused(res, r"result.toml: parameters: expected dict, got int", load_result, ResultError)


def test_mount_needs_a_last_row_of_0_0_0_1(unit):
    doc = tomllib.loads((unit / "capture.toml").read_text())
    doc["cameras"][1]["mount"][3][3] = 2.0
    (unit / "capture.toml").write_text(tomli_w.dumps(doc))
    refused(unit, r"cameras.uav1.mount: the last row must be \[0, 0, 0, 1\], got \[0.0, 0.0, 0.0, 2.0\]")


@pytest.mark.parametrize(
    ("kind", "field", "value", "message"),
    [
        ("gps", "sigma", 1e300, r"gps.npz: sigma: 1e\+300 is outside \(0, 100000\] m"),
        ("gps", "sigma", 0.0, r"gps.npz: sigma: 0 is outside \(0, 100000\] m"),
        ("gps", "position", 1e300, r"gps.npz: position: 1e\+300 is outside \[-1e\+08, 1e\+08\] m"),
        ("imu", "accel", 1e300, r"imu.npz: accel: 1e\+300 is outside \[-10000, 10000\] m/s²"),
        ("imu", "gyro", -1e300, r"imu.npz: gyro: -1e\+300 is outside"),
        ("self_pose", "position", 1e300, r"self_pose.npz: position: 1e\+300 is outside"),
    ],
)
def test_sensor_values_out_of_physical_range_are_refused_with_the_range(unit, kind, field, value, message):
    file = unit / f"cameras/uav1/sensors/{kind}.npz"
    with np.load(file) as data:
        arrays = {k: data[k] for k in data.files}
    arrays[field] = np.full_like(arrays[field], value)
    np.savez(file, **arrays)
    refused(unit, message)


@pytest.mark.parametrize(
    ("stamps", "message"),
    [
        (np.arange(6) * 1e-12, r"timestamps: samples 0 and 1 are 1e-12 s apart; at least 1e-06 s expected"),
        (np.arange(6) * 1e6, r"timestamps: spans 5e\+06 s, more than 1e\+06 s"),
        (1e300 + np.arange(6), r"timestamps: 1e\+300 is outside \[-1e\+10, 1e\+10\] s"),
    ],
)
def test_clocks_that_would_explode_a_time_grid_are_refused(unit, stamps, message):
    np.save(unit / TIMESTAMPS, stamps)
    refused(unit, message)


# --- paths ------------------------------------------------------------------------------------


def test_a_nul_byte_a_symlink_loop_or_a_long_name_in_a_path_is_refused(unit):
    edit_manifest(unit, f'timestamps = "{TIMESTAMPS}"', 'timestamps = "cameras/\\u0000x.npy"')
    refused(unit, r"cameras.static0.timestamps: path 'cameras/\\x00x.npy' cannot be used \(embedded null byte\)")
    edit_manifest(unit, 'timestamps = "cameras/\\u0000x.npy"', 'timestamps = "loop.npy"')
    (unit / "loop.npy").symlink_to("loop.npy")
    refused(unit, r"cameras.static0.timestamps: path 'loop.npy' cannot be used \(.*[Ss]ymlink loop")
    edit_manifest(unit, 'timestamps = "loop.npy"', f'timestamps = "{"a" * 5000}"')
    refused(unit, r"cameras.static0.timestamps: path 'a+' cannot be used \(\[Errno 36\] File name too long")
    assert main(["capture", "info", str(unit)]) == 2


def test_a_camera_named_with_a_dot_round_trips(tmp_path):
    capture = make_capture()
    capture.cameras[0].name = "cam.1"
    capture.ground_truth.cameras = {"cam.1": capture.ground_truth.cameras["static0"], "uav1": capture.ground_truth.cameras["uav1"]}
    loaded = load_capture(write_capture(capture, tmp_path / "cap"))
    assert [c.name for c in loaded.cameras] == ["cam.1", "uav1"]
    np.testing.assert_allclose(loaded.ground_truth.cameras["cam.1"], capture.ground_truth.cameras["cam.1"], atol=1e-12)


# --- misspelt keys ----------------------------------------------------------------------------


def test_a_misspelt_key_is_named_with_the_nearest_known_one(unit, caplog):
    edit_manifest(unit, 'extrinsics = "cameras/static0', 'extrinsic = "cameras/static0')
    edit_manifest(unit, 'world_frame = "ENU test"', 'wrld_frame = "ENU test"')
    with caplog.at_level(logging.WARNING, logger="mocapgraph"):
        capture = load_capture(unit)
    assert capture.camera("static0").extrinsics is None  # ignored, as the warning says
    assert "capture.toml: cameras.static0.extrinsic: unknown key ignored; did you mean 'extrinsics'?" in caplog.text
    assert "capture.toml: wrld_frame: unknown key ignored; did you mean 'world_frame'?" in caplog.text
    assert "seed" not in caplog.text  # the user's own metadata draws no warning


# --- through the command line -------------------------------------------------------------------


def test_the_cli_prints_one_error_line_and_exits_2(unit, capsys):
    (unit / DETECTOR).write_bytes(b"")
    assert main(["capture", "info", str(unit)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mocapgraph: error: cameras/static0/detector_openpose.npz: not a readable .npz file")


def test_a_camera_clock_offset_by_an_epoch_ends_in_a_clean_error_not_terabytes(tmp_path, capsys):
    """Issue 19: 1e9 s of offset made ``run baseline`` ask for 224 GiB; now the cameras are seen
    not to share frames, with memory to spare."""
    from mocapgraph.data_tools.sim.synthetic import synthesize

    capture = synthesize("rich", seed=0, duration_s=0.5)
    cam = capture.cameras[1]
    cam.timestamps = cam.timestamps + 1e9
    capture.ground_truth.cameras.pop(cam.name)
    capture.ground_truth.swaps.pop(cam.name, None)
    path = write_capture(capture, tmp_path / "cap")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert main(["run", "baseline", str(path), "--out", str(tmp_path / "out"), "-q"]) == 2
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200 * 1024  # KiB
    assert f"camera {cam.name!r}: no frame within" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_the_error_type_is_the_one_users_see():
    assert issubclass(CaptureError, MocapgraphError) and issubclass(ResultError, MocapgraphError)


# --- importers: calibrations and keypoint files -------------------------------------------------


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("calib.json", b"[" * 100000 + b"]" * 100000, r"calib.json: not valid JSON \(nested too deeply\)"),
        ("calib.toml", b"x = " + b"[" * 5000 + b"]" * 5000, r"calib.toml: not valid TOML \(nested too deeply\)"),
        ("calib.json", b'{"cam": "\xff"}', r"calib.json: not a text file; calibrations are .* \(byte 9 is not UTF-8\)"),
    ],
)
def test_a_damaged_calibration_file_is_refused(tmp_path, name, content, message):
    from mocapgraph.data_tools.io.calibration import read_calibration

    (tmp_path / name).write_bytes(content)
    with pytest.raises(CaptureError, match=message):
        read_calibration(tmp_path / name)


K_TOML = "K = [[1000, 0, 500], [0, 1000, 400], [0, 0, 1]]\n"


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        ("dist = [1e10, 0, 0, 0, 0]\n", r"calib.toml: cam1.distortion: 1e\+10 is outside \[-1000, 1000\]"),
        ("R = [0, 0, 0]\nT = [1e300, 0, 0]\n", r"calib.toml: cam1.T \(its camera centre\): -1e\+300 is outside \[-1e\+08, 1e\+08\] m"),
        ("size = [1e9, 1080]\n", r"calib.toml: cam1.image_size: 1e\+09 is outside \[1, 100000\] px"),
    ],
)
def test_a_calibration_value_out_of_range_names_the_calibration_file(tmp_path, lines, message):
    """Refused where it is read, not later against the capture written from it."""
    from mocapgraph.data_tools.io.calibration import read_calibration

    (tmp_path / "calib.toml").write_text("[cam1]\n" + K_TOML + lines)
    with pytest.raises(CaptureError, match=message):
        read_calibration(tmp_path / "calib.toml")


def test_a_keypoint_array_with_a_huge_header_is_refused(tmp_path):
    from mocapgraph.data_tools.io.keypoint_files import read_keypoint_array

    (tmp_path / "kp.npy").write_bytes(huge_header())
    with pytest.raises(CaptureError, match=r"kp.npy: shape \(1000000000000, 22, 3\) would need"):
        read_keypoint_array(tmp_path / "kp.npy")
    (tmp_path / "kp.npz").write_bytes(b"PK\x03\x04 cut")
    with pytest.raises(CaptureError, match=r"kp.npz: not a readable .npz file"):
        read_keypoint_array(tmp_path / "kp.npz")
