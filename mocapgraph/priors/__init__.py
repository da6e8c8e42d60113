"""Learned priors on the body, trained on CMU motion retargeted onto our body model.

- :class:`PoseGMM` / :func:`fit_pose_gmm`: a Gaussian mixture over the 63-d joint-rotation vector
  (``docs/priors.md``), and :func:`pose_gmm_factor`, its max-mixture GTSAM factor.
- :func:`load_default_pose_gmm`: the mixture shipped in ``mocapgraph/priors/data``.
- :mod:`~mocapgraph.priors.pose_vae` / ``pose_vae_factor``, :mod:`~mocapgraph.priors.motion_vae` /
  ``motion_factor``: the pose VAE and SmartMocap's motion VAE with their latent-variable factors;
- :mod:`~mocapgraph.priors.fusion_regressor`: AirPose-like multi-view initialiser;
- training (``training``, ``fusion_training``, ``motion_windows``) on ``data_tools.sim``'s CMU takes.

May import ``body``, ``factors`` and ``data_tools`` (training data); ``graphs`` and the pipelines
use it.
"""

from __future__ import annotations

from pathlib import Path

from mocapgraph.priors.gmm_factor import pose_gmm_factor
from mocapgraph.priors.pose_gmm import PoseGMM, fit_pose_gmm

DEFAULT_POSE_GMM = Path(__file__).parent / "data" / "pose_gmm.npz"


def load_default_pose_gmm() -> PoseGMM:
    """The shipped pose GMM (8 components, Anny body, trained on CMU subjects 01–79 minus a held-out fifth)."""
    return PoseGMM.load(DEFAULT_POSE_GMM)


__all__ = ["DEFAULT_POSE_GMM", "PoseGMM", "fit_pose_gmm", "load_default_pose_gmm", "pose_gmm_factor"]
