"""Exports read back by readers that share no code with the writers, joints compared per frame.

Tolerances: the text formats round to 1e-6 (metres, degrees), so joints come back within 1e-5 m;
glTF stores float32, whose rounding at metre scale through a 10-bone chain stays under 2e-5 m.
"""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.body import JOINT_NAMES, load_body_model
from mocapgraph.body.rotations import axis_rotation, rotvec_to_matrix
from mocapgraph.data_tools.io.exporters import ExportError, export_result
from mocapgraph.data_tools.io.result import CameraTrack, Result

Z_UP_FROM_Y_UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # Blender's import of a Y-up file


@pytest.fixture(scope="module")
def anny():
    return load_body_model("anny")


def body_result(body, frames: int = 6, seed: int = 0) -> Result:
    """A short random motion of ``body`` with one moving camera."""
    rng = np.random.default_rng(seed)
    root = random_root(rng, frames)
    pose = rng.normal(scale=0.35, size=(frames, 21, 3))
    shape = np.clip(body.default_shape + rng.normal(scale=0.1, size=body.shape_dim), *body.shape_bounds.T)
    fk = body.forward(shape, root, pose)
    return Result(
        pipeline="unit", capture="none", world_frame="capture", timestamps=10.0 + np.arange(frames) / 25.0,
        joints=fk.joints, body_model=body.name, root=root, pose=pose, shape=shape,
        keypoints=fk.keypoints[:, :17], keypoint_format="coco17",
        cameras={"cam0": CameraTrack(10.0 + np.arange(frames + 2) / 25.0 - 0.04, random_root(rng, frames + 2))},
    )  # fmt: skip


def joints_only(result: Result) -> Result:
    joints = result.joints.copy()
    joints[2, 5] = np.nan  # a joint the baseline could not triangulate
    return Result(pipeline="baseline", capture="none", world_frame="capture", timestamps=result.timestamps, joints=joints)


# ---- BVH: a minimal parser written from the format's description -----------------------------


def euler_matrix(channels: list[str], degrees: np.ndarray) -> np.ndarray:
    """``(T, 3, 3)`` the product of the channels' elementary rotations in the order listed."""
    R = np.tile(np.eye(3), (len(degrees), 1, 1))
    for k, name in enumerate(channels):
        R = R @ axis_rotation(name[0].lower(), np.radians(degrees[:, k]))
    return R


def read_bvh(text: str) -> tuple[dict[str, np.ndarray], float]:
    """World positions ``{joint: (T, 3)}`` of a BVH file (in its own Y-up frame) and its frame time."""
    head, motion = text.split("MOTION")
    joints, stack, order = {}, [], []
    pending = None
    for line in head.splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] in ("ROOT", "JOINT"):
            pending = {"name": words[1], "parent": stack[-1] if stack else None}
        elif words[0] == "End":
            pending = {"name": None, "parent": stack[-1]}
        elif words[0] == "{":
            stack.append(pending["name"])
            if pending["name"] is not None:
                joints[pending["name"]] = pending
        elif words[0] == "}":
            stack.pop()
        elif words[0] == "OFFSET" and stack[-1] is not None:
            joints[stack[-1]]["offset"] = np.array(words[1:], dtype=float)
        elif words[0] == "CHANNELS":
            joints[stack[-1]]["channels"] = words[2:]
            order.append(stack[-1])
    lines = motion.strip().splitlines()
    frames = int(lines[0].split(":")[1])
    frame_time = float(lines[1].split(":")[1])
    values = np.array([row.split() for row in lines[2 : 2 + frames]], dtype=float)
    column, world = 0, {}
    for name in order:
        joint, n = joints[name], len(joints[name]["channels"])
        data, channels = values[:, column : column + n], joint["channels"]
        column += n
        position = np.zeros((frames, 3)) + joint["offset"]
        for k, ch in enumerate(channels):
            if ch.endswith("position"):
                position[:, "XYZ".index(ch[0])] += data[:, k]
        rot = [k for k, ch in enumerate(channels) if ch.endswith("rotation")]
        local = euler_matrix([channels[k] for k in rot], data[:, rot])
        if joint["parent"] is None:
            world[name] = (local, position)
        else:
            R_p, p_p = world[joint["parent"]]
            world[name] = (R_p @ local, p_p + np.einsum("txy,ty->tx", R_p, position))
    return {n: p for n, (_, p) in world.items()}, frame_time


def test_bvh_round_trip(tmp_path, anny):
    result = body_result(anny)
    path = export_result(result, "bvh", tmp_path / "motion.bvh")
    positions, frame_time = read_bvh(path.read_text())
    assert list(positions) == [JOINT_NAMES[j] for j in [0, 1, 4, 7, 10, 2, 5, 8, 11, 3, 6, 9, 12, 15, 13, 16, 18, 20, 14, 17, 19, 21]]
    joints = np.stack([positions[n] for n in JOINT_NAMES], axis=1) @ Z_UP_FROM_Y_UP.T
    np.testing.assert_allclose(joints, result.joints, atol=1e-5)
    assert frame_time == pytest.approx(0.04)


def test_bvh_is_upright_in_its_own_frame(tmp_path, anny):
    """A body standing upright in our Z-up world stands along +Y in the file (BVH's up)."""
    result = body_result(anny, frames=2)
    result.root[:, :3, :3] = axis_rotation("x", np.pi / 2)  # body +Y (up) onto world +Z
    result.pose[:] = 0.0
    result.joints = anny.forward(result.shape, result.root, result.pose).joints
    positions, _ = read_bvh(export_result(result, "bvh", tmp_path / "upright.bvh").read_text())
    rise = positions["head"] - positions["pelvis"]
    assert rise[0, 1] > 0.4 and np.abs(rise[0, [0, 2]]).max() < 0.1


# ---- glTF: pygltflib decodes, the test composes the node transforms itself ------------------

COMPONENTS = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
WIDTHS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def accessor_array(gltf, blob: bytes, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    width = WIDTHS[acc.type]
    data = np.frombuffer(blob, COMPONENTS[acc.componentType], acc.count * width, view.byteOffset + (acc.byteOffset or 0))
    return data.reshape(acc.count, width) if width > 1 else data


def trs(translation, rotation) -> np.ndarray:
    x, y, z, w = np.asarray(rotation, dtype=float).T
    M = np.zeros(np.shape(x) + (4, 4))
    M[..., 0, :3] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1)
    M[..., 1, :3] = np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1)
    M[..., 2, :3] = np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)
    M[..., :3, 3], M[..., 3, 3] = translation, 1.0
    return M


def gltf_globals(gltf, blob: bytes, frames: int) -> np.ndarray:
    """``(T, N, 4, 4)`` every node's global transform at each keyframe of the body's animation."""
    local = np.array([trs(n.translation or [0, 0, 0], n.rotation or [0, 0, 0, 1]) for n in gltf.nodes])
    local = np.repeat(local[None], frames, axis=0)
    anim = gltf.animations[0]
    tracks: dict[int, dict[str, np.ndarray]] = {}
    for ch in anim.channels:
        sampler = anim.samplers[ch.sampler]
        tracks.setdefault(ch.target.node, {})[ch.target.path] = accessor_array(gltf, blob, sampler.output)
    for node, t in tracks.items():
        if len(t["translation"]) == frames:  # body bones (camera tracks have their own times)
            local[:, node] = trs(t["translation"], t["rotation"])
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    world = np.empty_like(local)
    for i in range(len(gltf.nodes)):  # parents precede children in our files; checked here
        assert parent.get(i, -1) < i
        world[:, i] = local[:, i] if i not in parent else world[:, parent[i]] @ local[:, i]
    return world


@pytest.fixture(scope="module")
def glb(tmp_path_factory, anny):
    pytest.importorskip("torch")
    pytest.importorskip("anny")
    result = body_result(anny)
    path = export_result(result, "gltf", tmp_path_factory.mktemp("gltf") / "motion.glb")
    return result, path


def test_gltf_joints_and_skinned_mesh_read_back(glb, anny):
    pygltflib = pytest.importorskip("pygltflib")
    result, path = glb
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    T = len(result.timestamps)
    world = gltf_globals(gltf, blob, T)
    names = [n.name for n in gltf.nodes]
    joint_bones = gltf.scenes[0].extras["joint_bones"]
    heads = np.stack([np.mean([world[:, names.index(b), :3, 3] for b in joint_bones[j]], axis=0) for j in JOINT_NAMES], axis=1)
    np.testing.assert_allclose(heads @ Z_UP_FROM_Y_UP.T, result.joints, atol=2e-5)

    # The skinned mesh by the glTF formula, against the body's own skinning (Anny-exact, tested in test_body_mesh).
    skin = gltf.skins[0]
    inverse_bind = accessor_array(gltf, blob, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    prim = gltf.meshes[0].primitives[0]
    attrs = prim.attributes
    position = accessor_array(gltf, blob, attrs.POSITION).astype(float)
    joints = np.concatenate([accessor_array(gltf, blob, getattr(attrs, f"JOINTS_{s}")) for s in range(3)], axis=1)
    weights = np.concatenate([accessor_array(gltf, blob, getattr(attrs, f"WEIGHTS_{s}")) for s in range(3)], axis=1).astype(float)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-6)
    matrices = world[:, skin.joints] @ inverse_bind  # (T, B, 4, 4)
    frame = T - 1
    moved = np.einsum("vkxy,vy->vkx", matrices[frame][joints][..., :3, :3], position) + matrices[frame][joints][..., :3, 3]
    vertices = np.einsum("vk,vkx->vx", weights, moved) @ Z_UP_FROM_Y_UP.T
    mesh = anny.mesh(result.shape)
    expected = mesh.vertices(mesh.bone_poses(anny.forward(result.shape, result.root[frame:], result.pose[frame:])))[0]
    np.testing.assert_allclose(vertices, expected, atol=2e-5)
    assert len(accessor_array(gltf, blob, prim.indices)) == 3 * len(mesh.faces)

    # The camera node at its own keyframes, under the world node: world_T_camera with glTF's camera axes.
    node = names.index("camera cam0")
    anim = gltf.animations[0]
    samplers = {ch.target.path: anim.samplers[ch.sampler] for ch in anim.channels if ch.target.node == node}
    times = accessor_array(gltf, blob, samplers["translation"].input)
    np.testing.assert_allclose(times, result.cameras["cam0"].timestamps - result.cameras["cam0"].timestamps[0], atol=1e-6)
    pose = trs(accessor_array(gltf, blob, samplers["translation"].output), accessor_array(gltf, blob, samplers["rotation"].output))[:, :3]
    expected = result.cameras["cam0"].world_T_camera
    np.testing.assert_allclose(pose[:, :, 3], expected[:, :3, 3], atol=1e-5)
    np.testing.assert_allclose(pose[:, :, :3] @ np.diag([1.0, -1.0, -1.0]), expected[:, :3, :3], atol=1e-6)


def test_gltf_loads_in_trimesh(glb, anny):
    trimesh = pytest.importorskip("trimesh")
    result, path = glb
    scene = trimesh.load(str(path), force="scene")
    (geometry,) = scene.geometry.values()
    mesh = anny.mesh(result.shape)
    assert geometry.faces.shape == mesh.faces.shape
    # trimesh shows a skinned mesh in its bind pose (the body frame, Y up as glTF).
    np.testing.assert_allclose(np.sort(geometry.vertices, axis=0), np.sort(mesh.bind_vertices, axis=0), atol=1e-6)


# ---- TRC and CSV: the standard library's csv reader ------------------------------------------


def test_trc_round_trip(tmp_path, anny):
    result = body_result(anny)
    path = export_result(result, "trc", tmp_path / "markers.trc")
    rows = list(csv.reader(path.read_text().splitlines(), delimiter="\t"))
    assert rows[0][3] == "markers.trc"
    header = dict(zip(rows[1], rows[2]))
    assert header["Units"] == "m" and float(header["DataRate"]) == pytest.approx(25.0) and int(header["NumMarkers"]) == 22 + 17
    markers = [m for m in rows[3][2:] if m]
    assert markers[:2] == ["joint_pelvis", "joint_left_hip"] and markers[22] == "nose"
    data = np.array([[float(v) for v in row[2:]] for row in rows[5:]]).reshape(len(result.timestamps), -1, 3)
    # Pose2Sim's Y-up: (x, y, z) in the file is (y, z, x) of the Z-up world.
    world = data[..., [2, 0, 1]]
    np.testing.assert_allclose(world[:, :22], result.joints, atol=1e-5)
    np.testing.assert_allclose(world[:, 22:], result.keypoints, atol=1e-5)
    np.testing.assert_allclose([float(r[1]) for r in rows[5:]], result.timestamps - result.timestamps[0], atol=1e-6)


def test_trc_and_csv_of_a_joints_only_result_keep_missing_joints_empty(tmp_path, anny):
    result = joints_only(body_result(anny))
    rows = list(csv.reader(export_result(result, "trc", tmp_path / "j.trc").read_text().splitlines(), delimiter="\t"))
    assert rows[7][2 + 15 : 2 + 18] == ["", "", ""]  # frame 3 (row 8), joint 5
    table = list(csv.DictReader(export_result(result, "csv", tmp_path / "j.csv").read_text().splitlines()))
    assert table[2]["right_knee_x_m"] == ""
    got = np.array([[float(row[f"{n}_{a}_m"] or "nan") for n in JOINT_NAMES for a in "xyz"] for row in table]).reshape(result.joints.shape)
    np.testing.assert_allclose(got, result.joints, atol=1e-6)
    np.testing.assert_allclose([float(row["time_s"]) for row in table], result.timestamps, atol=1e-6)


# ---- SMPL / AMASS .npz: posed again with the SMPL backend ------------------------------------


@pytest.fixture(scope="module")
def smpl(tmp_path_factory):
    """The SMPL backend on a random model file in the distributed layout, and its arrays."""
    from test_smpl_backend import SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, make_model_arrays

    arrays = make_model_arrays(6890, SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, seed=4)
    model_file = tmp_path_factory.mktemp("smpl") / "SMPL_NEUTRAL.npz"
    np.savez(model_file, **arrays)
    return load_body_model("smpl", model_file), arrays


def test_smpl_npz_round_trip(tmp_path, smpl):
    smpl, arrays = smpl
    result = body_result(smpl)
    data = np.load(export_result(result, "smpl", tmp_path / "motion.npz", body=smpl))
    assert data["poses"].shape == (6, 72) and str(data["gender"]) == "neutral" and float(data["mocap_framerate"]) == pytest.approx(25.0)
    np.testing.assert_array_equal(data["poses"][:, 66:], 0.0)  # SMPL's hand joints are not estimated
    # SMPL: joint 0 sits at J0(β) + trans and the root turns about it.
    J = arrays["J_regressor"] @ (arrays["v_template"] + arrays["shapedirs"][:, :, :10] @ data["betas"])
    root = np.tile(np.eye(4), (6, 1, 1))
    root[:, :3, :3] = rotvec_to_matrix(data["root_orient"])
    root[:, :3, 3] = data["trans"] + J[0]
    joints = smpl.forward(data["betas"], root, data["pose_body"].reshape(6, 21, 3)).joints
    np.testing.assert_allclose(joints, result.joints, atol=1e-9)


def test_gltf_of_an_smpl_result(tmp_path, smpl):
    """SMPL's mesh on its 22 joints: the joints read back from the bone nodes."""
    pygltflib = pytest.importorskip("pygltflib")
    smpl, arrays = smpl
    result = body_result(smpl)
    gltf = pygltflib.GLTF2().load(str(export_result(result, "gltf", tmp_path / "smpl.glb", body=smpl)))
    world = gltf_globals(gltf, gltf.binary_blob(), len(result.timestamps))
    names = [n.name for n in gltf.nodes]
    heads = np.stack([world[:, names.index(j), :3, 3] for j in JOINT_NAMES], axis=1)
    np.testing.assert_allclose(heads @ Z_UP_FROM_Y_UP.T, result.joints, atol=2e-5)
    assert gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION].count == len(arrays["v_template"])


# ---- What cannot be exported, and bad input ---------------------------------------------------


@pytest.mark.parametrize("fmt", ["bvh", "gltf", "smpl"])
def test_joints_only_results_name_what_is_missing(tmp_path, anny, fmt):
    suffix = {"gltf": ".glb", "smpl": ".npz"}.get(fmt, f".{fmt}")
    with pytest.raises(ExportError, match="needs the body parameters .* baseline result has joints only; export trc or csv"):
        export_result(joints_only(body_result(anny)), fmt, tmp_path / f"x{suffix}")


def test_smpl_export_of_an_anny_result_is_refused(tmp_path, anny):
    with pytest.raises(ExportError, match="needs a result of the SMPL or SMPL-X backend; this one used anny"):
        export_result(body_result(anny), "smpl", tmp_path / "x.npz")


def test_bad_requests_are_one_clear_error(tmp_path, anny):
    result = body_result(anny)
    with pytest.raises(ExportError, match="unknown export format 'fbx'; choose one of bvh, gltf, trc, csv, smpl"):
        export_result(result, "fbx", tmp_path / "x.fbx")
    with pytest.raises(ExportError, match=re.escape("a gltf export is a .glb file; name it x.glb")):
        export_result(result, "gltf", tmp_path / "x.gltf")
    path = export_result(result, "csv", tmp_path / "x.csv")
    before = path.read_text()
    with pytest.raises(ExportError, match="already exists"):
        export_result(joints_only(result), "csv", path)
    assert path.read_text() == before
    export_result(joints_only(result), "csv", path, overwrite=True)
    assert path.read_text() != before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv"]  # no temporary file left behind



def test_export_command(tmp_path, anny, capsys):
    from mocapgraph.cli.main import main
    from mocapgraph.data_tools.io.result import write_result

    result = body_result(anny)
    path = write_result(result, tmp_path / "result")
    out = tmp_path / "motion.bvh"
    assert main(["export", str(path), "--format", "bvh", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out.resolve()}"
    positions, _ = read_bvh(out.read_text())
    np.testing.assert_allclose(positions["head"] @ Z_UP_FROM_Y_UP.T, result.joints[:, 15], atol=1e-5)
    for args, message in (
        ([str(path), "--format", "bvh", "--out", str(out)], "motion.bvh: already exists (pass overwrite=True / --overwrite"),
        ([str(tmp_path / "missing"), "--format", "csv", "--out", str(tmp_path / "x.csv")], "missing: directory not found"),
        ([str(path), "--format", "trc", "--out", str(tmp_path / "x.csv")], "a trc export is a .trc file; name it x.trc"),
    ):
        assert main(["export", *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith("mocapgraph: error: ") and message in err and "Traceback" not in err
