"""Qualisys ``.qca.txt`` calibrations: units, axes and the video field of view.

``LAB`` is the calibration of Pose2Sim's ``Demo_MultiPerson`` clip (pose2sim 0.10.49 wheel,
``Pose2Sim/Demo_MultiPerson/calibration/Calib.qca.txt``, BSD-3-Clause, (c) David Pagnon): four
portrait 1088x1920 video cameras around a lab floor whose centre is the world origin, z up.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from mocapgraph.data_tools.io.calibration import QUALISYS_SUBPIXELS, intrinsics_only, read_calibration
from mocapgraph.data_tools.io.capture import CaptureError

LAB = """<?xml version='1.0' encoding='ASCII'?>
<calibration created="sometimes ago" longArmEnd="none" longArmMiddle="none" maximumFrames="none" qtm-version="none" shortArmEnd="none" source="calibration_qca_rotated.qca.txt" type="regular" wandLength="none">
  <results min-max-diff="0." std-dev="0."/>
  <cameras>
    <camera active="1" avg-residual="0.402000" model="none" point-count="999999999" serial="cam01" viewrotation="0">
      <fov_marker bottom="1919" left="0" right="1087" top="0"/>
      <fov_marker_max bottom="1919" left="0" right="1087" top="0"/>
      <fov_video bottom="1919" left="0" right="1087" top="0"/>
      <fov_video_max bottom="1919" left="0" right="1087" top="0"/>
      <transform r11="0.5536380477336265" r12="0.8046719867383512" r13="0.2144479094331626" r21="-0.4345300743838753" r22="0.05946489349975602" r23="0.8986921279821063" r31="0.7104002579937896" r32="-0.5907342212870501" r33="0.3825762057979294" x="1460.2323709212087" y="-1909.1590482454608" z="1896.5058524092062"/>
      <intrinsic centerPointU="34110.316406" centerPointV="60680.792969" focalLengthU="107599.671875" focalLengthV="107588.828125" focallength="9.314096596679686" radialDistortion1="-0.046183" radialDistortion2="0.139983" radialDistortion3="0.000000" sensorMaxU="69568" sensorMaxV="122816" sensorMinU="0.000000" sensorMinV="0.000000" skew="0.000000" tangentalDistortion1="0.000608" tangentalDistortion2="0.00069"/>
    </camera>
    <camera active="1" avg-residual="0.444749" model="none" point-count="999999999" serial="cam02" viewrotation="0">
      <fov_marker bottom="1919" left="0" right="1087" top="0"/>
      <fov_marker_max bottom="1919" left="0" right="1087" top="0"/>
      <fov_video bottom="1919" left="0" right="1087" top="0"/>
      <fov_video_max bottom="1919" left="0" right="1087" top="0"/>
      <transform r11="-0.1966832217091926" r12="0.979523227309506" r13="-0.043011131806342306" r21="-0.31478107085300017" r22="-0.02153908797812718" r23="0.9489198834051846" r31="0.9285626460991909" r32="0.20017570994064315" r33="0.3125717476340885" x="2582.0136248568124" y="706.5662881637625" z="1690.9818366061595"/>
      <intrinsic centerPointU="34207.652344" centerPointV="61646.457031" focalLengthU="107118.695313" focalLengthV="107123.023438" focallength="9.272462063031563" radialDistortion1="-0.047847" radialDistortion2="0.136786" radialDistortion3="0.000000" sensorMaxU="69568" sensorMaxV="122816" sensorMinU="0.000000" sensorMinV="0.000000" skew="0.000000" tangentalDistortion1="0.000972" tangentalDistortion2="0.000291"/>
    </camera>
    <camera active="1" avg-residual="0.450323" model="none" point-count="999999999" serial="cam03" viewrotation="0">
      <fov_marker bottom="1919" left="0" right="1087" top="0"/>
      <fov_marker_max bottom="1919" left="0" right="1087" top="0"/>
      <fov_video bottom="1919" left="0" right="1087" top="0"/>
      <fov_video_max bottom="1919" left="0" right="1087" top="0"/>
      <transform r11="-0.740641130147863" r12="-0.6704153360235378" r13="-0.044654154988568895" r21="0.25251118212268814" r22="-0.3393170985114385" r23="0.9061467925015139" r31="-0.6226466246887545" r32="0.6598539110153292" r33="0.4205995683324882" x="-3216.86586729648" y="2231.1786368869416" z="2088.19103027083"/>
      <intrinsic centerPointU="32845.335938" centerPointV="61120.328125" focalLengthU="107622.296875" focalLengthV="107616.632813" focallength="9.316055073242188" radialDistortion1="-0.046705" radialDistortion2="0.137622" radialDistortion3="0.000000" sensorMaxU="69568" sensorMaxV="122816" sensorMinU="0.000000" sensorMinV="0.000000" skew="0.000000" tangentalDistortion1="-0.000542" tangentalDistortion2="-0.000517"/>
    </camera>
    <camera active="1" avg-residual="0.504772" model="none" point-count="999999999" serial="cam04" viewrotation="0">
      <fov_marker bottom="1919" left="0" right="1087" top="0"/>
      <fov_marker_max bottom="1919" left="0" right="1087" top="0"/>
      <fov_video bottom="1919" left="0" right="1087" top="0"/>
      <fov_video_max bottom="1919" left="0" right="1087" top="0"/>
      <transform r11="0.2586331447643361" r12="-0.875095795920923" r13="-0.40904308378315923" r21="0.49590579729377593" r22="-0.24310718522469382" r23="0.8336524076031634" r31="-0.8289670298870364" r32="-0.4184569804097585" r33="0.3710895025551282" x="-3758.720480260634" y="-1415.6654017496533" z="1881.7941041388026"/>
      <intrinsic centerPointU="34566.796875" centerPointV="61697.9375" focalLengthU="107215.039063" focalLengthV="107213.070313" focallength="9.280801818890938" radialDistortion1="-0.047633" radialDistortion2="0.134667" radialDistortion3="0.000000" sensorMaxU="69568" sensorMaxV="122816" sensorMinU="0.000000" sensorMinV="0.000000" skew="0.000000" tangentalDistortion1="0.000277" tangentalDistortion2="0.000199"/>
    </camera>
  </cameras>
</calibration>
"""


def camera_point(cam, X) -> np.ndarray:
    """``X (3,)`` world → the camera's OpenCV frame (x right, y down, z forward)."""
    return (np.linalg.inv(cam.world_T_camera) @ np.append(X, 1.0))[:3]


def pixel(cam, X) -> np.ndarray:
    x = camera_point(cam, X)
    return (cam.K @ x)[:2] / x[2]


@pytest.fixture
def lab(tmp_path):
    path = tmp_path / "Calib.qca.txt"
    path.write_text(LAB)
    return path


def test_known_values(lab):
    cams = read_calibration(lab)
    assert [c.name for c in cams] == ["cam01", "cam02", "cam03", "cam04"]
    cam = cams[0]
    assert QUALISYS_SUBPIXELS == 64
    np.testing.assert_allclose(
        cam.K, [[107599.671875 / 64, 0, 34110.316406 / 64], [0, 107588.828125 / 64, 60680.792969 / 64], [0, 0, 1]], rtol=1e-15
    )
    assert cam.K[0, 0] == pytest.approx(1681.24, abs=0.01)
    assert cam.image_size == (1088, 1920)
    np.testing.assert_array_equal(cam.distortion, [-0.046183, 0.139983, 0.000608, 0.00069, 0.0])  # k1 k2 p1 p2 k3
    np.testing.assert_allclose(cam.world_T_camera[:3, 3], [1.4602323709212087, -1.9091590482454608, 1.8965058524092062], rtol=1e-15)
    R = cam.world_T_camera[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_the_lab_is_in_view_and_upright(lab):
    """Every camera stands 2-5 m from the floor centre, 1.6-2.2 m up, and sees the floor centre
    inside its image, in front of it, with the vertical upright in the image (portrait video)."""
    for cam in read_calibration(lab):
        centre = cam.world_T_camera[:3, 3]
        assert 2.0 < np.linalg.norm(centre) < 5.0 and 1.6 < centre[2] < 2.2, cam.name
        assert camera_point(cam, np.zeros(3))[2] > 2.0, cam.name
        u, v = pixel(cam, np.zeros(3))
        assert 0 <= u < cam.image_size[0] and 0 <= v < cam.image_size[1], (cam.name, u, v)
        # a point 1 m above the floor centre is higher in the image, and nearly straight above
        du, dv = pixel(cam, np.array([0.0, 0.0, 1.0])) - (u, v)
        assert dv < -300 and abs(du) < 0.5 * abs(dv), (cam.name, du, dv)
        # the optical axis points at the floor centre to within 20 degrees
        axis = cam.world_T_camera[:3, 2]
        assert np.degrees(np.arccos(axis @ -centre / np.linalg.norm(centre))) < 20, cam.name


def test_intrinsics_only_keeps_the_lens(lab):
    full = read_calibration(lab)
    for a, b in zip(full, intrinsics_only(full)):
        assert b.world_T_camera is None and a.world_T_camera is not None
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.distortion, b.distortion)
        assert a.image_size == b.image_size


def test_field_of_view_offsets_the_principal_point(tmp_path):
    path = tmp_path / "crop.qca.txt"
    path.write_text(LAB.replace('<fov_video bottom="1919" left="0" right="1087" top="0"/>', '<fov_video bottom="1499" left="100" right="1019" top="40"/>', 1))
    cam = read_calibration(path)[0]
    assert cam.image_size == (920, 1460)
    np.testing.assert_allclose(cam.K[:2, 2], [34110.316406 / 64 - 100, 60680.792969 / 64 - 40], rtol=1e-15)


def test_content_is_recognised_without_the_extension(tmp_path):
    (tmp_path / "lab.xml").write_text(LAB)
    assert [c.name for c in read_calibration(tmp_path / "lab.xml")] == ["cam01", "cam02", "cam03", "cam04"]


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda s: s.replace('focalLengthU="107599.671875" ', "", 1), ["camera cam01: intrinsic.focalLengthU: missing"]),
        (lambda s: s.replace('focalLengthV="107123.023438"', 'focalLengthV="abc"', 1), ["camera cam02: intrinsic.focalLengthV: not a number ('abc')"]),
        (lambda s: re.sub(r"<intrinsic [^>]*/>", "", s, count=1), ["camera cam01: no <intrinsic> element", "needs every camera's intrinsics"]),
        (lambda s: s.replace('r11="0.5536380477336265"', 'r11="0.9"', 1), ["camera cam01: transform.r11..r33: not a rotation matrix"]),
        (lambda s: s.replace('skew="0.000000"', 'skew="2.5"', 1), ["camera cam01: intrinsic.skew: 2.5"]),
        (lambda s: s.replace("<fov_video ", "<fov_other ", 1), ["camera cam01: fov_video: missing"]),
        (lambda s: s.replace('serial="cam02"', 'serial="cam01"', 1), ["camera names must be unique", "cam01"]),
        (lambda s: s.replace("</cameras>", "", 1), ["not valid XML"]),
    ],
)  # fmt: skip
def test_bad_files_name_the_file_and_camera(tmp_path, edit, words):
    path = tmp_path / "Calib.qca.txt"
    path.write_text(edit(LAB))
    with pytest.raises(CaptureError) as err:
        read_calibration(path)
    assert str(err.value).startswith(f"{path}: ")
    for word in words:
        assert word in str(err.value)


def test_inactive_cameras_are_skipped_and_units_are_stated(lab, caplog):
    lab.write_text(LAB.replace('active="1" avg-residual="0.444749"', 'active="0" avg-residual="0.444749"'))
    assert [c.name for c in read_calibration(lab)] == ["cam01", "cam03", "cam04"]
    assert "camera cam02 is marked inactive; skipped" in caplog.text
    assert len(read_calibration(lab, units="mm")) == 3
    with pytest.raises(CaptureError, match="Qualisys calibrations are in millimetres and say so; leave out units='m'"):
        read_calibration(lab, units="m")
