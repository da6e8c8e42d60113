"""``mocapgraph priors train pose|motion|fusion``: train the learned priors on CMU motion.

Each flag's default is the training function's (read from its signature).
"""

from __future__ import annotations

import logging
from pathlib import Path

from mocapgraph.cli.common import add_body_args, body_from, command, function_flags, group

log = logging.getLogger("mocapgraph.priors")
MOTION_DIR = ("CMU motion directory (default ../shared/motion/cmu_train)", {"type": Path, "metavar": "DIR", "flag": "--motion"})


def _training_args(args, names: list[str]) -> dict:
    from mocapgraph.data_tools.sim.cmu_motion import motion_dir

    kw = {name: getattr(args, name) for name in names}
    kw["motion_dir"] = kw["motion_dir"] or motion_dir()
    return kw


def _report(path: Path, info: dict, held_out: str, rows: dict[str, str], fitting: str = "training") -> None:
    """The held-out subjects, one line per measured number, the time and the file written."""
    print(f"held-out subjects {', '.join(map(str, info['val_subjects']))}: {held_out}")
    rows = {**rows, "time": f"{info['load_seconds']:.1f} s loading, {info['fit_seconds']:.1f} s {fitting}"}
    for name, value in rows.items():
        print(f"  {name:25s} {value}")
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")


def cmd_train_pose(args) -> None:
    if args.model == "gmm":
        from mocapgraph.priors.training import train_pose_prior

        gmm = train_pose_prior(body=body_from(args), progress=log.info, **_training_args(args, args.gmm_parameters))
        info = gmm.info
        _report(gmm.save(args.out), info, f"{info['val_poses']} poses", {
            "mean log-likelihood": f"{info['val_mean_log_likelihood']:.2f} nats (training poses: {info['train_mean_log_likelihood']:.2f})",
            "nearest-mean geodesic": f"{info['val_nearest_mean_geodesic_rad']:.3f} rad per joint",
        }, fitting="EM")  # fmt: skip
    else:
        from mocapgraph.priors.pose_vae import train_pose_vae

        vae = train_pose_vae(body=body_from(args), progress=log.info, **_training_args(args, args.vae_parameters))
        info = vae.info
        _report(vae.save(args.out, float16=True), info, f"{info['val_poses']} poses", {
            "reconstruction geodesic": f"{info['val_geodesic_err_rad']:.3f} rad per modelled joint",
            "ELBO": f"{info['val_elbo']:.2f} nats per pose",
        })  # fmt: skip


def cmd_train_motion(args) -> None:
    from mocapgraph.priors.motion_vae import train_motion_vae

    vae = train_motion_vae(body=body_from(args), progress=log.info, **_training_args(args, args.parameters))
    info = vae.info
    _report(vae.save(args.out), info, f"{info['val_windows']} windows", {
        "position error": f"{1000 * info['val_mpjpe_m']:.1f} mm per joint (decode(encode(window)))",
        "model": f"width {info['width']}, latent {info['latent']}, {info['parameters']} parameters",
    })  # fmt: skip


def cmd_train_fusion(args) -> None:
    from mocapgraph.priors.fusion_training import train_fusion_regressor

    regressor = train_fusion_regressor(body=body_from(args), progress=log.info, **_training_args(args, args.parameters))
    info, val = regressor.info, regressor.info["val"]
    _report(regressor.save(args.out), info, f"{val['frames']} bodies, 2 views each", {
        "root-relative MPJPE": f"{1000 * val['mpjpe_m']:.0f} mm (camera frame)",
        "root position": f"{val['root_position_m']:.2f} m (depth {val['root_depth_m']:.2f} m, rotation {val['root_rotation_deg']:.1f}°)",
        "camera 2 in camera 1": f"{val['relative_camera_m']:.2f} m, {val['relative_camera_deg']:.1f}°",
    })  # fmt: skip


def add_parsers(subparsers) -> None:
    from mocapgraph.priors.fusion_training import train_fusion_regressor
    from mocapgraph.priors.motion_vae import train_motion_vae
    from mocapgraph.priors.pose_vae import train_pose_vae
    from mocapgraph.priors.training import train_pose_prior

    priors = group(subparsers, "priors", "learned priors: training", "priors_command")
    train = priors.add_parser("train", help="train a prior on CMU motion").add_subparsers(dest="prior", required=True, metavar="PRIOR")

    pose = command(train, "pose", "pose prior: Gaussian mixture or VAE (docs/priors.md)")
    pose.add_argument("--model", choices=("gmm", "vae"), default="gmm", help="which pose prior (default gmm)")
    pose.add_argument("--out", type=Path, required=True, metavar="FILE", help=".npz file to write")
    # Both models' flags share a namespace: their common ones (data, seed) are read from the GMM's trainer.
    gmm = function_flags(pose, train_pose_prior, {"motion_dir": MOTION_DIR, "components": "gmm: mixture components", "seed": "seed of the initialisation and the subject split"})
    vae = function_flags(pose, train_pose_vae, {"latent": "vae: latent size", "width": "vae: hidden width", "epochs": "vae: training epochs"})
    add_body_args(pose)
    pose.set_defaults(func=cmd_train_pose, gmm_parameters=gmm, vae_parameters=["motion_dir", "seed", *vae])

    motion = command(train, "motion", "SmartMocap motion VAE over 25-frame windows (docs/priors.md)")
    motion.add_argument("--out", type=Path, required=True, metavar="FILE", help=".npz file to write")
    names = function_flags(
        motion, train_motion_vae,
        {"motion_dir": MOTION_DIR, "width": "convolution channels", "latent": "latent size", "epochs": "training epochs",
         "stride": "frames between training windows", "seed": "seed of the weights, the batches and the subject split"},
    )  # fmt: skip
    add_body_args(motion)
    motion.set_defaults(func=cmd_train_motion, parameters=names)

    fusion = command(train, "fusion", "multi-view fusion regressor: body and camera-relative root from 2D keypoints (docs/fusion-regressor.md)")
    fusion.add_argument("--out", type=Path, required=True, metavar="FILE", help=".npz file to write")
    names = function_flags(
        fusion, train_fusion_regressor,
        {"motion_dir": MOTION_DIR, "variant": ("ablation variant", {"choices": ("full", "no_exchange", "no_crop")}), "epochs": "training epochs",
         "samples": "synthetic samples per epoch, fresh cameras each", "seed": "seed of the weights, the synthetic views and the subject split"},
    )  # fmt: skip
    add_body_args(fusion)
    fusion.set_defaults(func=cmd_train_fusion, parameters=names)
