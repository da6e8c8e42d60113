"""The body's skinned mesh posed by the 22 joints, against each backend's own skinning: the anny
package's forward pass, and plain SMPL linear blend skinning over all of SMPL's joints."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_root
from test_smpl_backend import SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, make_model_arrays, reference_posed

from mocapgraph.body import load_body_model
from mocapgraph.errors import MocapgraphError


def test_anny_posed_mesh_and_bones_match_anny():
    torch = pytest.importorskip("torch")
    pytest.importorskip("anny")
    from mocapgraph.body.anny_backend import _anny_model

    body = load_body_model("anny")
    rng = np.random.default_rng(5)
    shape = np.array([0.2, 0.7, 0.4, 0.6, 0.3, 0.5])
    root, pose = random_root(rng, 3), rng.normal(scale=0.5, size=(3, 21, 3))
    mesh = body.mesh(shape)
    bones = mesh.bone_poses(body.forward(shape, root, pose))
    model = _anny_model()
    deltas = {k: torch.from_numpy(v) for k, v in body.anny_pose(root, pose).items()}
    phenotypes = {n: torch.full((3,), float(v), dtype=torch.float64) for n, v in zip(body.shape_names, shape)}
    out = model(pose_parameters=deltas, phenotype_kwargs=phenotypes)
    np.testing.assert_allclose(bones, out["bone_poses"].numpy(), atol=1e-12)
    np.testing.assert_allclose(mesh.vertices(bones), out["vertices"].numpy(), atol=1e-12)
    np.testing.assert_allclose(mesh.joints(bones), body.forward(shape, root, pose).joints, atol=1e-12)
    assert mesh.faces.shape == (27420, 3) and mesh.faces.max() == mesh.num_vertices - 1
    np.testing.assert_allclose(mesh.skin_weights.sum(axis=1), 1.0, atol=1e-12)


@pytest.fixture(scope="module")
def smpl_file(tmp_path_factory):
    arrays = make_model_arrays(6890, SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, seed=1)
    path = tmp_path_factory.mktemp("smpl") / "SMPL_NEUTRAL.npz"
    np.savez(path, **arrays)
    return path, arrays


def test_smpl_posed_mesh_matches_plain_lbs(smpl_file):
    path, arrays = smpl_file
    body = load_body_model("smpl", path)
    rng = np.random.default_rng(2)
    shape = rng.normal(size=10)
    root, pose = random_root(rng, 2), rng.normal(scale=0.5, size=(2, 21, 3))
    mesh = body.mesh(shape)
    bones = mesh.bone_poses(body.forward(shape, root, pose))
    vertices = mesh.vertices(bones)
    for t in range(2):
        joints, expected = reference_posed(arrays, shape, root[t], pose[t])
        np.testing.assert_allclose(vertices[t], expected, atol=1e-10)
        np.testing.assert_allclose(mesh.joints(bones)[t], joints, atol=1e-10)
    np.testing.assert_array_equal(mesh.faces, arrays["f"])


def test_a_model_file_without_triangles_has_no_mesh(smpl_file, tmp_path):
    _, arrays = smpl_file
    np.savez(tmp_path / "SMPL_NEUTRAL.npz", **{k: v for k, v in arrays.items() if k != "f"})
    smpl = load_body_model("smpl", tmp_path / "SMPL_NEUTRAL.npz")
    with pytest.raises(MocapgraphError, match=r"SMPL_NEUTRAL.npz: has no triangles \(field 'f'\), so no mesh"):
        smpl.mesh(smpl.default_shape)
