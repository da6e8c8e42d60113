"""``mocapgraph plot``: a result drawn to a PNG, and an existing picture refused."""

from __future__ import annotations

import numpy as np

from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.result import CameraTrack, Result, write_result


def test_plot_draws_a_result_and_refuses_to_overwrite(tmp_path, capsys):
    import matplotlib.image

    T = 10
    joints = np.random.default_rng(0).normal(scale=0.3, size=(T, 22, 3)) + [0, 0, 1]
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, :3, 3] = [3.0, 0.0, 1.5]
    result = Result("smartmocap", "cap", "ground_plane", np.arange(T) / 30.0, joints, cameras={"cam1": CameraTrack(np.arange(T) / 30.0, poses)})
    path = write_result(result, tmp_path / "res")
    assert main(["plot", str(path)]) == 0
    png = path / "result.png"
    assert f"wrote {png.resolve()}" in capsys.readouterr().out
    image = matplotlib.image.imread(png)
    assert image.shape[0] > 400 and image.shape[1] > 400 and image[..., :3].std() > 0.05  # not blank
    assert main(["plot", str(path)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert not list(path.glob(".*tmp*"))  # written atomically
