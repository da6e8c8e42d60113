"""``mocapgraph bench priors``: the shipped learned priors measured in one run.

1. **Held-out data.** Takes of the subjects that every shipped prior held out in training (the
   split is by subject and seeded, so the three files agree; checked) are retargeted afresh:
   the pose VAE's reconstruction error, the GMM's log-likelihood and the motion VAE's position
   error on windows every 25 frames.
2. **Real against corrupted motion.** The motion VAE's ELBO of the held-out windows, and of the
   same windows with the motion corrupted before it is cut into windows: jitter (5° on every
   joint rotation and 2 cm on the root, per frame), foot skating (the root gliding at 1.25 m/s
   while the legs move as recorded) and a 90° root flip (the body tipped over about its own
   right-left axis). Each gap is ``ELBO(real) − ELBO(corrupted)``, nats per window.
3. **Jacobian cost.** One batched decoder evaluation with forward-mode Jacobians for 72 windows
   (the windows of a 60 s capture), per window, as the graph runs it (in chunks of 8 windows).
4. **AirCap under heavy keypoint noise.** One ``aircap`` capture driven by a held-out CMU walk,
   every detector's noise multiplied by ``noise_scale``, solved with each prior and without.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.errors import MocapgraphError

HELD_OUT_TAKE = "cmu_15_01_s1.npz"  # "walk/wander", 41 s, subject 15 (held out by every shipped prior)
VARIANTS = {
    # name: (the graph's pose prior, the motion prior)
    "none": ("none", "none"),
    "pose_gmm": ("gmm", "none"),
    "pose_vae": ("vae", "none"),
    "motion_vae": ("none", "vae"),
}


def held_out_takes(motion_dir: Path, subjects: list[int]) -> list[Path]:
    """The takes of ``subjects`` in ``motion_dir``, in name order."""
    from mocapgraph.priors.training import take_files, take_subject

    return [path for path in take_files(motion_dir) if take_subject(path) in subjects]


def corrupt(kind: str, root: np.ndarray, pose: np.ndarray, rng: np.random.Generator, fps: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """A corrupted copy of a motion ``root (T, 4, 4)`` world_T_root, ``pose (T, 21, 3)``.

    ``jitter``: per frame, 5° (0.087 rad) Gaussian noise on every joint's axis-angle and 2 cm on
    the root position. ``skate``: the root glides along world +X at 1.25 m/s on top of the
    recorded motion, the legs unchanged. ``flip``: every root orientation turned 90° about its own
    X axis (the body's left-right axis), the root position kept, so the body lies on its back.
    """
    root, pose = root.copy(), pose.copy()
    if kind == "jitter":
        pose += rng.normal(scale=np.deg2rad(5.0), size=pose.shape)
        root[:, :3, 3] += rng.normal(scale=0.02, size=(len(root), 3))
    elif kind == "skate":
        root[:, 0, 3] += 1.25 * np.arange(len(root)) / fps
    elif kind == "flip":
        root[:, :3, :3] = root[:, :3, :3] @ axis_rotation("x", np.pi / 2)
    else:
        raise MocapgraphError(f"unknown corruption {kind!r}")
    return root, pose


def _held_out_numbers(motion_dir: Path, out: dict) -> None:
    from mocapgraph.data_tools.sim.cmu_motion import load_cmu_take, retarget
    from mocapgraph.priors import load_default_pose_gmm
    from mocapgraph.priors.motion_vae import decoder_jacobian_ms, load_default_motion_vae
    from mocapgraph.priors.motion_windows import WINDOW, motion_features, window_starts
    from mocapgraph.priors.pose_vae import load_default_pose_vae
    from mocapgraph.priors.training import nearest_mean_geodesic

    body = load_body_model()
    gmm, pose_vae, motion_vae = load_default_pose_gmm(), load_default_pose_vae(), load_default_motion_vae()
    subjects = sorted(pose_vae.info["val_subjects"])
    for name, model in (("pose GMM", gmm), ("motion VAE", motion_vae)):
        if sorted(model.info["val_subjects"]) != subjects:
            raise MocapgraphError(f"the shipped {name} held out subjects {model.info['val_subjects']}, the pose VAE {subjects}")
    out["val_subjects"] = subjects
    # Each take is retargeted once, for the poses (every `stride`-th frame, as the pose priors
    # were trained) and for the windows.
    stride = pose_vae.info["stride"]
    rng = np.random.default_rng(0)
    frames, windows = [], {"real": [], "jitter": [], "skate": [], "flip": []}
    for path in held_out_takes(motion_dir, subjects):
        root, pose = retarget(load_cmu_take(path), body)
        frames.append(pose[::stride].reshape(-1, 63))
        starts = window_starts(len(root), WINDOW)
        if not len(starts):
            continue
        windows["real"].append(motion_features(body, root, pose, starts))
        for kind in ("jitter", "skate", "flip"):
            windows[kind].append(motion_features(body, *corrupt(kind, root, pose, rng), starts))
    poses = np.concatenate(frames)
    out["val_poses"] = len(poses)
    out["pose_vae_val_err_rad"] = round(float(pose_vae.geodesic_error(poses).mean()), 4)
    out["pose_gmm_val_log_likelihood"] = round(float(gmm.log_likelihood(poses).mean()), 2)
    out["pose_gmm_val_nearest_mean_rad"] = round(float(nearest_mean_geodesic(gmm, poses).mean()), 4)
    stacked = {k: np.concatenate(v) for k, v in windows.items()}
    out["val_windows"] = len(stacked["real"])
    out["motion_vae_val_mpjpe_m"] = round(float(motion_vae.reconstruction_mpjpe(stacked["real"]).mean()), 4)
    elbo = {k: float(motion_vae.elbo(v).mean()) for k, v in stacked.items()}
    out["motion_elbo_real"] = round(elbo["real"], 1)
    for kind in ("jitter", "skate", "flip"):
        out[f"motion_elbo_{kind}"] = round(elbo[kind], 1)
        out[f"motion_elbo_gap_{kind}"] = round(elbo["real"] - elbo[kind], 1)
    out["motion_jacobian_windows"] = 72
    out["motion_prior_jacobian_ms_per_window"] = round(decoder_jacobian_ms(motion_vae, windows=72), 2)


def _aircap_rows(motion_dir: Path, duration_s: float, seed: int, noise_scale: float, out: dict) -> None:
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.aircap import AircapOptions, run_aircap

    take = motion_dir / HELD_OUT_TAKE
    capture = synthesize("aircap", seed=seed, duration_s=duration_s, motion=str(take), noise_scale=noise_scale)
    out["aircap"] = {"duration_s": duration_s, "seed": seed, "noise_scale": noise_scale, "motion": HELD_OUT_TAKE}
    for name, (pose_prior, motion_prior) in VARIANTS.items():
        options = AircapOptions(covariances=False, motion_prior=motion_prior)
        options.graph.pose_prior = pose_prior
        result = run_aircap(capture, options)
        metrics = evaluate(result, capture).metrics
        sequence_s = result.parameters["seconds"] - result.parameters["per_frame_seconds"]
        out["aircap"][name] = {
            **{k: round(metrics[k], 4) for k in ("ra_mpjpe_m", "pa_mpjpe_m", "mpjpe_m")},
            "sequence_seconds": round(sequence_s, 2),
        }
        out[f"ra_mpjpe_m_{name}"] = out["aircap"][name]["ra_mpjpe_m"]
    seq = {name: row["sequence_seconds"] for name, row in out["aircap"].items() if isinstance(row, dict)}
    out["motion_prior_sequence_time_ratio"] = round(seq["motion_vae"] / seq["none"], 3)
    out["pose_vae_sequence_time_ratio"] = round(seq["pose_vae"] / seq["none"], 3)


def bench_priors(motion_dir: str | Path | None = None, duration_s: float = 10.0, seed: int = 0, noise_scale: float = 3.0) -> dict:
    """Every number of the module docstring as one dict (JSON-ready)."""
    from mocapgraph.data_tools.sim.cmu_motion import motion_dir as default_motion_dir

    directory = Path(motion_dir) if motion_dir is not None else default_motion_dir()
    out: dict = {"motion_dir": str(directory)}
    start = time.perf_counter()
    _held_out_numbers(directory, out)
    _aircap_rows(directory, duration_s, seed, noise_scale, out)
    out["seconds"] = round(time.perf_counter() - start, 1)
    return out
