"""The batched decoder: one network run per linearisation, outputs and Jacobians exact."""

import gtsam
import numpy as np
import pytest
import torch

from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import motion_latent_key, pose_latent_key
from mocapgraph.priors.latent import BatchedDecoder, latent_prior_factor


def _net(L=3, R=5):
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(L, 8), torch.nn.GELU(), torch.nn.Linear(8, R))


def test_one_batched_run_serves_every_key_and_matches_the_network():
    net = _net()
    keys = [pose_latent_key(i) for i in range(4)]
    dec = BatchedDecoder(net, keys, 3)
    values = gtsam.Values()
    Z = np.random.default_rng(1).normal(size=(4, 3))
    for k, z in zip(keys, Z):
        values.insert(k, z)
    outs = [dec(values, k, jacobian=True) for k in keys]
    assert dec.evaluations == 1
    with torch.no_grad():
        expected = net(torch.as_tensor(Z, dtype=torch.float32)).double().numpy()
    # float32 network: a few ulps of each output's magnitude
    np.testing.assert_allclose([o for o, _ in outs], expected, rtol=64 * np.finfo(np.float32).eps, atol=64 * np.finfo(np.float32).eps)
    # Jacobian against central differences of the network in float64.
    net64 = net.double()
    for (_, J), z in zip(outs, Z):
        numeric = np.zeros((5, 3))
        for a in range(3):
            d = np.zeros(3)
            d[a] = 1e-6
            with torch.no_grad():
                hi, lo = (net64(torch.as_tensor(z + s * d)[None])[0].numpy() for s in (1, -1))
            numeric[:, a] = (hi - lo) / 2e-6
        np.testing.assert_allclose(J, numeric, atol=1e-4)


def test_a_changed_latent_triggers_a_new_run_and_cost_only_calls_skip_jacobians():
    dec = BatchedDecoder(_net(), [motion_latent_key(0), motion_latent_key(1)], 3)
    values = gtsam.Values()
    values.insert(motion_latent_key(0), np.zeros(3))
    values.insert(motion_latent_key(1), np.ones(3))
    out0, J = dec(values, motion_latent_key(0), jacobian=False)
    assert J is None and dec.evaluations == 1
    dec(values, motion_latent_key(1), jacobian=False)
    assert dec.evaluations == 1
    dec(values, motion_latent_key(1), jacobian=True)  # the Jacobian was not computed yet
    assert dec.evaluations == 2
    values.update(motion_latent_key(0), np.full(3, 0.5))
    out1, _ = dec(values, motion_latent_key(0), jacobian=False)
    assert dec.evaluations == 3 and not np.allclose(out0, out1)


def test_latents_missing_from_the_values_are_skipped():
    dec = BatchedDecoder(_net(), [pose_latent_key(0), pose_latent_key(1)], 3)
    values = gtsam.Values()
    values.insert(pose_latent_key(1), np.ones(3))
    out, J = dec(values, pose_latent_key(1), jacobian=True)
    assert out.shape == (5,) and J.shape == (5, 3)


def test_latent_prior_is_half_the_squared_norm():
    values = gtsam.Values()
    values.insert(pose_latent_key(0), np.array([1.0, -2.0, 0.5]))
    assert np.isclose(latent_prior_factor(pose_latent_key(0), 3).error(values), 0.5 * (1 + 4 + 0.25))
    assert np.isclose(latent_prior_factor(pose_latent_key(0), 3, sigma=3.0).error(values), 0.5 * (1 + 4 + 0.25) / 9)
    with pytest.raises(MocapgraphError, match="sigma"):
        latent_prior_factor(pose_latent_key(0), 3, sigma=0.0)
