"""The body's skinned mesh posed by the 22 joints, against the anny package's own forward pass."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.body import load_body_model

torch = pytest.importorskip("torch")
pytest.importorskip("anny")


@pytest.fixture(scope="module")
def body():
    return load_body_model("anny")


def test_posed_mesh_and_bones_match_anny(body):
    from mocapgraph.body.anny_backend import _anny_model

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


def test_a_backend_without_a_mesh_says_so(tmp_path):
    from test_smpl_backend import SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, make_model_arrays

    from mocapgraph.errors import MocapgraphError

    np.savez(tmp_path / "SMPL_NEUTRAL.npz", **make_model_arrays(6890, SMPL_JOINTS, SMPL_PARENTS, SMPL_VERTICES, seed=1))
    smpl = load_body_model("smpl", tmp_path / "SMPL_NEUTRAL.npz")
    with pytest.raises(MocapgraphError, match="the smpl body model has no mesh in mocapgraph"):
        smpl.mesh(smpl.default_shape)
