"""glTF 2.0 binary (``.glb``) of a result: the body's skinned mesh, its bones' animation, and the
camera tracks as animated cameras.

Scene: a node ``world`` turns our Z-up world into glTF's Y up (:data:`Y_UP_FROM_Z_UP`); under it
hang the body's bone rig (Anny: 104 bones, named as in Anny; the bones that move relative to their
parent are animated, the rest keep a fixed offset) and one node per camera track, animated with
the track's own timestamps (seconds from the earliest timestamp in the file). A camera node
carries a perspective camera when the capture's intrinsics are known (glTF cameras look down −Z
with +Y up, so the node is ``world_T_camera · diag(1, −1, −1)``). The mesh node sits at the scene
root as the glTF spec asks of skinned meshes; its skin uses the rig's bind pose (the body frame,
metres), with all of a vertex's bone weights (up to 12, in ``JOINTS_0..2``/``WEIGHTS_0..2``), so
a glTF viewer poses the mesh exactly as :meth:`SkinnedMesh.vertices` does, up to float32.
``scene.extras.joint_bones`` names the bones whose heads make each of the 22 joints.

Written with numpy and ``struct`` only (the format is a JSON chunk and a binary chunk).
"""

from __future__ import annotations

import json
import struct

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.data_tools.io.exporters import Y_UP_FROM_Z_UP

FLOAT, UINT8, UINT16, UINT32 = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
OPENCV_TO_GLTF_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])
"""A camera's axes, OpenCV (x right, y down, z forward) to glTF (x right, y up, looking down −z)."""
MOTION_TOLERANCE = 1e-9
"""A bone whose local transform varies less than this (metres, rotation-matrix entries) is static."""


class GlbBuilder:
    """Accumulates glTF JSON and one binary buffer; each array gets its own 4-byte-aligned view."""

    def __init__(self):
        self.doc: dict = {"asset": {"version": "2.0", "generator": "mocapgraph"}, "buffers": [], "bufferViews": [], "accessors": []}
        self.chunks: list[bytes] = []
        self.offset = 0

    def accessor(self, array: np.ndarray, component: int, target: int | None = None, bounds: bool = False) -> int:
        """Add ``array (N, C)`` or ``(N,)`` (or ``(N, 4, 4)`` matrices, written column-major)."""
        array = np.asarray(array)
        if array.ndim == 3:
            array = np.swapaxes(array, 1, 2).reshape(len(array), 16)
        dtype = {FLOAT: np.float32, UINT8: np.uint8, UINT16: np.uint16, UINT32: np.uint32}[component]
        data = np.ascontiguousarray(array, dtype=dtype)
        raw = data.tobytes()
        view = {"buffer": 0, "byteOffset": self.offset, "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        self.doc["bufferViews"].append(view)
        pad = (-len(raw)) % 4
        self.chunks.append(raw + b"\0" * pad)
        self.offset += len(raw) + pad
        width = 1 if data.ndim == 1 else data.shape[1]
        acc = {"bufferView": len(self.doc["bufferViews"]) - 1, "componentType": component, "count": len(data), "type": TYPES[width]}
        if bounds:
            flat = data.reshape(len(data), width)
            acc["min"], acc["max"] = flat.min(axis=0).tolist(), flat.max(axis=0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def glb(self) -> bytes:
        binary = b"".join(self.chunks)
        self.doc["buffers"] = [{"byteLength": len(binary)}]
        text = json.dumps(self.doc, separators=(",", ":")).encode("utf-8")
        text += b" " * ((-len(text)) % 4)
        total = 12 + 8 + len(text) + 8 + len(binary)
        return struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary


def continuous_quaternions(matrices: np.ndarray) -> np.ndarray:
    """``(T, 4)`` xyzw quaternions of ``(T, 3, 3)`` rotations, signs chosen so that neighbours agree
    (so that a viewer's interpolation takes the short way)."""
    q = Rotation.from_matrix(matrices).as_quat()
    flips = np.cumsum(np.r_[0, np.sum(q[1:] * q[:-1], axis=1) < 0]) % 2
    return q * np.where(flips, -1.0, 1.0)[:, None]


def add_animated_node(builder: GlbBuilder, node: dict, index: int, matrices: np.ndarray, times: int, animation: dict) -> None:
    """Set ``node``'s translation and rotation from ``matrices (T, 4, 4)``; animate them when T > 1
    (``times``: the accessor of the keyframe times)."""
    quats = continuous_quaternions(matrices[:, :3, :3])
    node["translation"], node["rotation"] = matrices[0, :3, 3].tolist(), quats[0].tolist()
    if len(matrices) < 2:
        return
    for path, values in (("translation", matrices[:, :3, 3]), ("rotation", quats)):
        animation["samplers"].append({"input": times, "output": builder.accessor(values, FLOAT), "interpolation": "LINEAR"})
        animation["channels"].append({"sampler": len(animation["samplers"]) - 1, "target": {"node": index, "path": path}})


def glb_bytes(result, body, capture=None) -> bytes:
    """The ``.glb`` file of the result's skinned mesh, bone animation and camera tracks."""
    mesh = body.mesh(result.shape)
    bones = mesh.bone_poses(body.forward(result.shape, result.root, result.pose))  # (T, B, 4, 4) world
    parents = mesh.bone_parents
    local = bones.copy()
    has_parent = parents >= 0
    local[:, has_parent] = np.linalg.inv(bones[:, parents[has_parent]]) @ bones[:, has_parent]
    moving = np.ptp(local, axis=0).max(axis=(1, 2)) > MOTION_TOLERANCE

    builder = GlbBuilder()
    doc = builder.doc
    start = min([result.timestamps[0]] + [track.timestamps[0] for track in result.cameras.values()])
    body_times = builder.accessor(result.timestamps - start, FLOAT, bounds=True)
    animation = {"name": "motion", "samplers": [], "channels": []}
    nodes: list[dict] = [{"name": "world", "rotation": Rotation.from_matrix(Y_UP_FROM_Z_UP).as_quat().tolist(), "children": []}]
    first_bone = len(nodes)
    for b, name in enumerate(mesh.bone_names):
        node = {"name": name}
        nodes.append(node)
        add_animated_node(builder, node, first_bone + b, local[:, b] if moving[b] else local[:1, b], body_times, animation)
        if parents[b] < 0:
            nodes[0]["children"].append(first_bone + b)
        else:
            nodes[first_bone + parents[b]].setdefault("children", []).append(first_bone + b)

    lenses = {cam.name: cam for cam in capture.cameras} if capture is not None else {}
    for name, track in result.cameras.items():
        index = len(nodes)
        node = {"name": f"camera {name}"}
        nodes.append(node)
        nodes[0]["children"].append(index)
        times = builder.accessor(track.timestamps - start, FLOAT, bounds=True) if len(track.timestamps) > 1 else body_times
        add_animated_node(builder, node, index, np.asarray(track.world_T_camera) @ OPENCV_TO_GLTF_CAMERA, times, animation)
        if name in lenses:
            cam = lenses[name]
            width, height = cam.image_size
            doc.setdefault("cameras", []).append(
                {"type": "perspective", "name": name,
                 "perspective": {"yfov": float(2 * np.arctan(height / (2 * cam.K[1, 1]))), "aspectRatio": width / height, "znear": 0.05}}
            )  # fmt: skip
            node["camera"] = len(doc["cameras"]) - 1

    slots = -(-mesh.skin_indices.shape[1] // 4) * 4
    indices = np.zeros((mesh.num_vertices, slots), dtype=np.int64)
    weights = np.zeros((mesh.num_vertices, slots))
    indices[:, : mesh.skin_indices.shape[1]] = mesh.skin_indices
    weights[:, : mesh.skin_weights.shape[1]] = mesh.skin_weights
    joint_type = UINT8 if len(mesh.bone_names) < 256 else UINT16
    attributes = {"POSITION": builder.accessor(mesh.bind_vertices, FLOAT, ARRAY_BUFFER, bounds=True)}
    for s in range(slots // 4):
        attributes[f"JOINTS_{s}"] = builder.accessor(indices[:, 4 * s : 4 * s + 4], joint_type, ARRAY_BUFFER)
        attributes[f"WEIGHTS_{s}"] = builder.accessor(weights[:, 4 * s : 4 * s + 4], FLOAT, ARRAY_BUFFER)
    faces = builder.accessor(mesh.faces.reshape(-1), UINT32, ELEMENT_ARRAY_BUFFER)
    doc["materials"] = [{"name": "body", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.62, 0.5, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.8}}]
    doc["meshes"] = [{"name": f"{body.name} body", "primitives": [{"attributes": attributes, "indices": faces, "material": 0, "mode": 4}]}]
    doc["skins"] = [{"name": "body", "joints": list(range(first_bone, first_bone + len(mesh.bone_names))),
                     "inverseBindMatrices": builder.accessor(np.linalg.inv(mesh.bind_poses), FLOAT),
                     "skeleton": first_bone + int(np.flatnonzero(parents < 0)[0])}]  # fmt: skip
    nodes.append({"name": "body mesh", "mesh": 0, "skin": 0})
    doc["nodes"] = nodes
    joint_bones = {j: [mesh.bone_names[b] for b in bones_of] for j, bones_of in zip(JOINT_NAMES, mesh.joint_bones)}
    doc["scenes"] = [{"name": result.pipeline, "nodes": [0, len(nodes) - 1],
                      "extras": {"joint_bones": joint_bones, "world_frame": result.world_frame, "up": "Y (our Z-up world turned by the world node)"}}]  # fmt: skip
    doc["scene"] = 0
    if animation["channels"]:
        doc["animations"] = [animation]
    return builder.glb()
