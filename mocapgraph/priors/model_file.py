"""The learned priors' one-file format: an ``.npz`` read without pickle.

Every prior stores ``format_version``, ``body_model`` and an ``info`` JSON string besides its own
arrays; network weights go under a key prefix (``state/<parameter name>``). Writing goes through
a temporary file and a rename, so a failed write never leaves a half-written model in place.
Reading checks the file, the required keys, the version and the weights' shapes, and every
error names the file and the key.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from mocapgraph.errors import MocapgraphError

STATE_PREFIX = "state/"


def write_model_file(path: str | Path, compressed: bool = False, **arrays) -> Path:
    """Write ``arrays`` to ``path`` atomically (``np.savez``, or ``savez_compressed``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    (np.savez_compressed if compressed else np.savez)(tmp, **arrays)
    os.replace(tmp, path)
    return path


def read_model_file(path: str | Path, kind: str, required: Sequence[str], version: int) -> dict[str, np.ndarray]:
    """Every array of the file ``path`` (a ``kind``, e.g. ``"pose VAE"``), once it is known to
    exist, to be a readable ``.npz``, to hold ``required`` and to have ``format_version == version``."""
    path = Path(path)
    if not path.exists():
        raise MocapgraphError(f"{path}: {kind} file not found")
    try:
        with np.load(path, allow_pickle=False) as d:
            arrays = {k: d[k] for k in d.files}
    except (OSError, ValueError) as exc:
        raise MocapgraphError(f"{path}: not a readable {kind} .npz ({exc})") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        raise MocapgraphError(f"{path}: missing key {missing[0]!r}")
    found = int(arrays["format_version"])
    if found != version:
        raise MocapgraphError(f"{path}: format_version {found}, this mocapgraph reads {version}")
    return arrays


def weight_arrays(module, dtype=np.float32) -> dict[str, np.ndarray]:
    """A torch module's parameters and buffers as ``state/<name>`` arrays of ``dtype``."""
    return {STATE_PREFIX + k: v.detach().cpu().numpy().astype(dtype) for k, v in module.state_dict().items()}


def load_weights(path: str | Path, module, arrays: dict[str, np.ndarray]) -> None:
    """Fill ``module`` from the ``state/<name>`` entries of ``arrays`` read from ``path`` (as
    float32); a missing or misshapen weight is an error naming the file and the key."""
    import torch

    state = {}
    for name, expected in module.state_dict().items():
        key = STATE_PREFIX + name
        if key not in arrays:
            raise MocapgraphError(f"{path}: missing key {key!r}")
        if arrays[key].shape != tuple(expected.shape):
            raise MocapgraphError(f"{path}: key {key!r} has shape {arrays[key].shape}, the config needs {tuple(expected.shape)}")
        state[name] = torch.as_tensor(arrays[key].astype(np.float32))
    module.load_state_dict(state)
