"""The command line: each subcommand's output, JSON contracts and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from test_capture import make_capture

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.capture import write_capture
from mocapgraph.data_tools.io.result import load_result


def test_body_info_lists_joints_keypoints_and_shape(capsys):
    assert main(["body", "info"]) == 0
    out = capsys.readouterr().out
    assert "21 right_wrist     [right_elbow]" in out
    assert "keypoints (23): nose," in out
    assert "height       range [0, 1]  default 0.5" in out


def test_body_info_json(capsys):
    assert main(["body", "info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["backend"] == "anny" and len(info["joints"]) == 22 and info["parents"][16] == 13
    assert [s["name"] for s in info["shape"]] == ["gender", "age", "muscle", "weight", "height", "proportions"]


def test_bench_body_json_contract(capsys):
    assert main(["bench", "body", "--json", "--frames", "16", "--seconds", "0.05"]) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("native_frames_per_s", "numpy_frames_per_s", "ratio", "max_jacobian_rel_err"):
        assert key in result
    assert result["max_jacobian_rel_err"] < 1e-6
    assert result["ratio"] == pytest.approx(result["native_frames_per_s"] / result["numpy_frames_per_s"], rel=0.01)


def test_bench_factors_json_contract(capsys):
    """Every camera count's timings, and its rows: 16 of coco17's 17 points detected per camera."""
    assert main(["bench", "factors", "--json", "--seconds", "0.01"]) == 0
    result = json.loads(capsys.readouterr().out)
    for cameras in (1, 4, 8):
        entry = result[f"C={cameras}"]
        assert entry["rows"] == 2 * 16 * cameras
        for key in ("error_us", "linearize_us", "labelled_error_us", "labelled_linearize_us", "kernel_us", "kernel_jacobians_us"):
            assert entry[key] > 0


def test_smpl_without_a_model_file_is_one_clear_error(capsys):
    assert main(["body", "info", "--backend", "smpl"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocapgraph: error: the smpl backend needs your own licensed model file")
    assert "Traceback" not in err


def test_missing_smpl_file_is_one_clear_error(tmp_path, capsys):
    assert main(["body", "info", "--backend", "smpl", "--model-path", str(tmp_path / "SMPL_NEUTRAL.npz")]) == 2
    err = capsys.readouterr().err
    assert "SMPL_NEUTRAL.npz" in err and err.count("\n") == 1


def test_demo_runs_aircap_and_smartmocap_and_draws_the_body(tmp_path, capsys):
    """The demo end to end on short captures; without a motion directory it uses built-in poses."""
    args = ["demo", "--out", str(tmp_path / "demo"), "--motion-dir", str(tmp_path / "no-motion"), "--duration", "1.5", "--phones-duration", "1.5"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "built-in poses: T-pose, stride, wave, squat" in out
    assert "sequence, cameras refined      MPJPE" in out
    report = tmp_path / "demo" / "report.html"
    assert report.exists() and "mpjpe_m" in report.read_text()
    for figure in ("root_trajectory.png", "error_per_frame.png"):
        assert (tmp_path / "demo" / figure).read_bytes()[:4] == b"\x89PNG"
    assert "SmartMocap, motion prior       MPJPE" in out
    smart = tmp_path / "demo" / "smartmocap"
    assert "static_mcpe_m" in (smart / "report.html").read_text()
    assert (smart / "camera_trajectories.png").read_bytes()[:4] == b"\x89PNG"
    png = tmp_path / "demo" / "body_poses.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert not list((tmp_path / "demo").glob("*.tmp*"))
    # The exports it links load back: the BVH's joints are the result's, the glTF opens in pygltflib.
    from test_exports import Z_UP_FROM_Y_UP, read_bvh

    page = report.read_text()
    assert page.count("<img ") == page.count('<img src="data:image/')  # one self-contained file
    assert 'href="exports/aircap.bvh"' in page and 'href="exports/aircap.glb"' in page and "mocapgraph view " in page
    result = load_result(tmp_path / "demo" / "result_sequence_refine")
    positions, _ = read_bvh((tmp_path / "demo" / "exports" / "aircap.bvh").read_text())
    np.testing.assert_allclose(positions["pelvis"] @ Z_UP_FROM_Y_UP.T, result.joints[:, 0], atol=1e-5)
    pygltflib = pytest.importorskip("pygltflib")
    gltf = pygltflib.GLTF2().load(str(tmp_path / "demo" / "exports" / "aircap.glb"))
    assert {f"camera {name}" for name in result.cameras} <= {n.name for n in gltf.nodes} and len(gltf.cameras) == len(result.cameras)
    for name in [*result.cameras, "mesh"]:
        assert f'data-file="overlays/{name}.png"' in page
        assert (tmp_path / "demo" / "overlays" / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "demo" / "overlays" / "mesh.gif").read_bytes()[:6] == b"GIF89a" and 'data-file="overlays/mesh.gif"' in page
    assert f"look at it: mocapgraph view {tmp_path / 'demo' / 'result_sequence_refine'}" in out


def test_capture_info_says_what_the_loader_repaired(tmp_path, capsys):
    path = write_capture(make_capture(), tmp_path / "cap")
    assert main(["capture", "info", str(path)]) == 0
    assert "repaired" not in capsys.readouterr().out
    np.save(path / "cameras/static0/timestamps.npy", np.array([0.0, 0.1, 0.2, 0.05, 0.15, 0.3]))
    assert main(["capture", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "  static0    static     4 frames over 0.3 s at 30 fps" in out
    assert out.endswith(
        "repaired while loading:\n"
        "  camera static0: timestamps (cameras/static0/timestamps.npy) go backwards at frame 3 (0.050 s after 0.200 s); "
        "dropped 2 of 6 frames that were not later than an earlier frame\n"
    )


def test_the_module_runs_and_prints_its_help():
    proc = subprocess.run([sys.executable, "-m", "mocapgraph.cli.main", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "usage: mocapgraph" in proc.stdout


@pytest.mark.parametrize(
    "args",
    [["body", "--help"], ["body", "info", "--help"], ["bench", "body", "--help"], ["bench", "aircap", "--help"],
     ["run", "aircap", "--help"], ["synth", "--help"], ["eval", "--help"], ["demo", "--help"], ["export", "--help"], ["overlay", "--help"],
     ["view", "--help"], ["colmap", "--help"], ["run", "smartmocap", "--help"], ["run", "online", "--help"]],
)  # fmt: skip
def test_every_subcommand_has_help(args, capsys):
    # in this process: a fresh interpreter per command costs 3 s of imports each
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 0 and "usage: mocapgraph" in capsys.readouterr().out


def test_priors_train_motion_on_a_tiny_motion_directory(tmp_path, capsys):
    from test_cmu_motion import write_take

    from mocapgraph.priors.motion_vae import MotionVAE

    for i, subject in enumerate((1, 2, 3, 4, 6)):
        write_take(tmp_path / f"cmu_{subject:02d}_01.npz", frames=40, seed=i)
    out = tmp_path / "motion.npz"
    args = ["priors", "train", "motion", "--motion", str(tmp_path), "--out", str(out), "--width", "8", "--latent", "4", "--epochs", "2"]
    assert main(args) == 0
    printed = capsys.readouterr()
    assert "epoch 2/2: " in printed.err and "position error" in printed.out
    vae = MotionVAE.load(out)
    assert vae.latent_dim == 4 and vae.info["train_windows"] + vae.info["val_windows"] == 5 * 4  # 40 frames: starts 0, 5, 10, 15
    assert main(["priors", "train", "motion", "--motion", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert "nowhere: motion directory not found" in capsys.readouterr().err


def test_priors_train_reads_the_default_motion_directory(tmp_path, monkeypatch, capsys):
    """Without --motion the trainers read $MOCAPGRAPH_MOTION_DIR (else ../shared/motion/cmu_train)."""
    from test_cmu_motion import write_take

    from mocapgraph.priors.pose_gmm import PoseGMM

    for i, subject in enumerate((1, 2, 3, 4, 6)):
        write_take(tmp_path / f"cmu_{subject:02d}_01.npz", frames=40, seed=i)
    monkeypatch.setenv("MOCAPGRAPH_MOTION_DIR", str(tmp_path))
    out = tmp_path / "gmm.npz"
    assert main(["priors", "train", "pose", "--out", str(out), "--components", "2", "-q"]) == 0
    assert "held-out subjects" in capsys.readouterr().out
    assert PoseGMM.load(out).info["data"] == tmp_path.name


def test_run_online_flags_set_the_options_and_bad_values_are_one_error(tmp_path, capsys):
    """``run online``'s tuning flags reach :class:`OnlineOptions` (numbers, ``rig``, ``none``);
    a bad value is the options' own error, exit code 2, before OUT is reserved."""
    from mocapgraph.cli.main import build_parser
    from mocapgraph.pipelines.online import OnlineOptions

    out = tmp_path / "out"
    base = ["run", "online", str(tmp_path / "capture"), "--out", str(out)]
    args = build_parser().parse_args(base + ["--uav-body-swaps", "none", "--unmodelled-sigma", "0.3", "--pose-sigma", "none", "--hips-sigma", "40", "--static-refine", "none", "--coast", "0.8", "--bootstrap-cameras", "prior"])
    options = args.options_from(args)
    assert (options.uav_body_swaps, options.unmodelled_sigma_rad, options.pose_sigma_rad_s2, options.hips_sigma_rad_s2) == ("none", 0.3, None, 40.0)
    assert (options.static_refine_s, options.coast_s, options.bootstrap_cameras) == (None, 0.8, "prior")
    options.check()
    defaults = build_parser().parse_args(base)
    assert defaults.options_from(defaults) == OnlineOptions()
    for flag, value, field in (("--unmodelled-sigma", "wide", "unmodelled_sigma_rad"), ("--hips-sigma", "-1", "hips_sigma_rad_s2"), ("--static-refine", "0", "static_refine_s")):
        assert main(base + [flag, value]) == 2
        err = capsys.readouterr().err
        assert err.startswith("mocapgraph: error: ") and field in err and "Traceback" not in err, err
        assert not out.exists()
    with pytest.raises(SystemExit):  # a word outside the choices: argparse's usage error
        main(base + ["--uav-body-swaps", "all"])
