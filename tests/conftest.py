"""Shared fixtures: a random body table whose shape dependence is known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.body.skeleton import NUM_JOINTS, PARENTS
from mocapgraph.body.table import BodyTable


class LinearShapeTable:
    """A random body whose offsets and markers are affine in a shape vector of size S."""

    def __init__(self, seed: int = 0, num_keypoints: int = 9, shape_dim: int = 4, names=None):
        rng = np.random.default_rng(seed)
        self.o0 = rng.normal(scale=0.2, size=(NUM_JOINTS, 3))
        self.o0[0] = 0.0
        self.do = rng.normal(scale=0.05, size=(NUM_JOINTS, 3, shape_dim))
        self.do[0] = 0.0
        weights = rng.random((num_keypoints, NUM_JOINTS)) * (rng.random((num_keypoints, NUM_JOINTS)) < 0.2)
        weights[np.arange(num_keypoints), rng.integers(0, NUM_JOINTS, num_keypoints)] += 0.5
        self.a = weights / weights.sum(axis=1, keepdims=True)
        self.l0 = rng.normal(scale=0.05, size=(num_keypoints, NUM_JOINTS, 3)) * (self.a[..., None] > 0)
        self.dl = rng.normal(scale=0.01, size=(num_keypoints, NUM_JOINTS, 3, shape_dim)) * (
            self.a[..., None, None] > 0
        )
        self.shape_dim = shape_dim
        self.names = tuple(names) if names is not None else tuple(f"k{i}" for i in range(num_keypoints))

    def __call__(self, beta: np.ndarray) -> BodyTable:
        return BodyTable(
            parents=PARENTS.copy(),
            offsets=self.o0 + self.do @ beta,
            d_offsets=self.do,
            weights=self.a,
            markers=self.l0 + self.dl @ beta,
            d_markers=self.dl,
            keypoint_names=self.names,
            mapped=np.ones(len(self.names), dtype=bool),
        )


def random_root(rng: np.random.Generator, frames: int) -> np.ndarray:
    """``(frames, 4, 4)`` random world_T_root poses."""
    root = np.tile(np.eye(4), (frames, 1, 1))
    root[:, :3, :3] = rotvec_to_matrix(rng.normal(size=(frames, 3)))
    root[:, :3, 3] = rng.normal(size=(frames, 3))
    return root


@pytest.fixture
def linear_table():
    return LinearShapeTable(seed=3)


@pytest.fixture(scope="module")
def one_torch_thread():
    """Torch on one thread for a module (restored after): training tiny networks is deterministic
    only at a fixed thread count, and faster on one thread of a shared 2-core machine."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


class RecordingBar:
    """Stands in for :func:`mocapgraph.progress.progress_bar`: records what it is told."""

    def __init__(self, iterable=None, *, total=None, desc="", unit=""):
        self.iterable, self.total, self.desc, self.unit, self.updates = iterable, total, desc, unit, 0
        self.made.append(self)

    def __iter__(self):
        for item in self.iterable:
            self.updates += 1
            yield item

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def update(self, n=1):
        self.updates += n

    def reset(self, total=None):
        self.total, self.updates = total, 0

    def close(self):
        pass


@pytest.fixture
def bars(monkeypatch):
    """``bars(module)`` replaces that module's ``progress_bar`` by :class:`RecordingBar`; returns the
    list of the bars it makes."""
    made: list[RecordingBar] = []

    def install(module) -> list[RecordingBar]:
        monkeypatch.setattr(module, "progress_bar", type("Bar", (RecordingBar,), {"made": made}))
        return made

    return install


@pytest.fixture(autouse=True)
def fresh_logging():
    """Every test starts with the ``mocapgraph`` loggers as a library user finds them: the
    command line's handler and level (set by a test that ran ``main``) do not leak."""
    import logging

    from mocapgraph.progress import ROOT_LOGGER

    logger = logging.getLogger(ROOT_LOGGER)
    yield
    for handler in list(logger.handlers):
        logger.removeHandler(handler)
    logger.setLevel(logging.NOTSET)
    logger.propagate = True


# ---------------------------------------------------------------------------------------------
# The real clip in tests/data/real (tests/real_clip.py)


@pytest.fixture(scope="session")
def clip():
    """Every person track of the real clip (:func:`real_clip.load_clip`)."""
    from real_clip import load_clip

    return load_clip()


@pytest.fixture(scope="session")
def lab():
    """The clip's Qualisys calibration by camera name."""
    from real_clip import calibration

    return {c.name: c for c in calibration()}
