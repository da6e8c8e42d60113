"""The checks every reader of captures, results and calibrations shares, so that any malformed
file ends in one :class:`~mocapgraph.errors.MocapgraphError` naming the file and the field.

Text is read with a size bound and parsed with deep nesting refused; ``.npy`` / ``.npz`` arrays
are read only after their headers have been checked against the bytes really there (a damaged
header cannot ask for more memory than the file holds); numbers are refused when they are
booleans, not finite or outside the physical range of their field (:data:`LIMITS`); unknown keys
of a table get a warning with the nearest known key.

``where`` arguments are :class:`~mocapgraph.data_tools.io.files.Where` places (anything with
``fail(message) -> Exception`` and ``__call__(sub) -> place``).
"""

from __future__ import annotations

import difflib
import json
import logging
import math
import os
import tokenize
import tomllib
import zipfile
import zlib
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

MAX_TEXT_BYTES = 64 << 20
"""Largest manifest, calibration or log file read: far beyond any real one (a few kB)."""

MAX_ARRAY_BYTES = 4 << 30
"""Largest single array read from a ``.npy`` / ``.npz`` file (an hour of 33 keypoints at 30 fps
is 86 MB); a bound on memory whatever a zip member claims to hold."""

NUMERIC_KINDS = "biuf"
"""dtype kinds an array file may hold: bool, integers, floats (not complex, dates, strings, records)."""


class Limit(NamedTuple):
    """A physical range: ``lo <= x <= hi`` (``lo < x`` when ``open_lo``), in ``unit``."""

    lo: float
    hi: float
    unit: str
    open_lo: bool = False

    def text(self) -> str:
        return f"{'(' if self.open_lo else '['}{self.lo:g}, {self.hi:g}] {self.unit}".rstrip()


LIMITS: dict[str, Limit] = {
    # Anything a pipeline meets must fit a float64 solve: a position of 1e300 m squares to inf.
    "position": Limit(-1e8, 1e8, "m"),  # beyond the Earth's ECEF radius (6.4e6 m) with room to spare
    "time": Limit(-1e10, 1e10, "s"),  # Unix time stays below 1e10 s until 2286
    "time_span": Limit(0.0, 1e6, "s"),  # one time axis: 11.6 days, far beyond any capture
    "time_step": Limit(1e-6, 1e6, "s"),  # a 1 MHz clock at most between samples
    "frame_rate": Limit(0.0, 1e4, "fps", open_lo=True),
    "pixel": Limit(-1e6, 1e6, "px"),  # intrinsics, keypoints and boxes: a million pixels off the image at most
    "image_size": Limit(1, 1e5, "px"),
    "distortion": Limit(-1e3, 1e3, ""),  # OpenCV k1 k2 p1 p2 k3 of real lenses stay within ±50
    "sigma_m": Limit(0.0, 1e5, "m", open_lo=True),  # GPS / barometer standard deviations
    "accel": Limit(-1e4, 1e4, "m/s²"),  # 1000 g
    "gyro": Limit(-1e4, 1e4, "rad/s"),
    "altitude": Limit(-1e5, 1e6, "m"),
    "body_parameter": Limit(-1e3, 1e3, ""),  # axis-angles (rad) and shape coefficients
}


# ---------------------------------------------------------------------------------------------
# Paths and text


def resolve_inside(root: Path, rel: str, where) -> Path:
    """``root / rel`` resolved, which must be an existing regular file inside ``root``."""
    try:
        path = (root / rel).resolve()
        inside = root.resolve() in path.parents
        is_file = path.is_file()
    except (OSError, ValueError, RuntimeError) as exc:  # NUL bytes, symlink loops, names too long
        raise where.fail(f"path {rel!r} cannot be used ({exc})") from None
    if not inside:
        raise where.fail(f"path {rel!r} points outside the directory")
    if not is_file:
        raise where.fail(f"file {rel!r} not found")
    return path


def read_text(path: Path, error: type[MocapgraphError], what: str = "a UTF-8 text file") -> str:
    """The text of ``path``: at most :data:`MAX_TEXT_BYTES`, UTF-8 without NUL characters."""
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_TEXT_BYTES + 1)
    except (OSError, ValueError) as exc:
        raise error(f"{path}: cannot be read ({exc})") from None
    if len(data) > MAX_TEXT_BYTES:
        raise error(f"{path}: larger than {MAX_TEXT_BYTES >> 20} MiB; not {what}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not {what} (byte {exc.start} is not UTF-8)") from None
    if "\0" in text:
        raise error(f"{path}: not {what} (it holds NUL bytes)")
    return text


def _parse(text: str, path: Path, error: type[MocapgraphError], kind: str, loads, decode_error: type[Exception]):
    """``loads(text)``, its decoding errors and runaway nesting as one ``error`` naming ``path``."""
    try:
        return loads(text)
    except decode_error as exc:
        raise error(f"{path}: not valid {kind} ({exc})") from None
    except RecursionError:
        raise error(f"{path}: not valid {kind} (nested too deeply)") from None


def parse_toml(text: str, path: Path, error: type[MocapgraphError]) -> dict:
    return _parse(text, path, error, "TOML", tomllib.loads, tomllib.TOMLDecodeError)


def parse_json(text: str, path: Path, error: type[MocapgraphError]):
    return _parse(text, path, error, "JSON", json.loads, json.JSONDecodeError)


# ---------------------------------------------------------------------------------------------
# Arrays

# What numpy's header parser and a damaged or cut file can raise, besides OSError/ValueError.
_ARRAY_ERRORS = (
    OSError, ValueError, EOFError, SyntaxError, TypeError, KeyError, IndexError, OverflowError,
    tokenize.TokenError, RecursionError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, NotImplementedError,
)  # fmt: skip


def _checked_header(f, available: int, label: str, error: type[MocapgraphError]) -> None:
    """Read an ``.npy`` header from ``f`` and refuse it unless it describes a plain numeric array
    whose data fits in the ``available`` bytes of the file (checked before anything is allocated)."""
    version = np.lib.format.read_magic(f)
    if version not in ((1, 0), (2, 0), (3, 0)):
        raise ValueError(f"unknown .npy version {version}")
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(f)
    if dtype.kind not in NUMERIC_KINDS or dtype.names is not None or dtype.subdtype is not None:
        raise error(f"{label}: holds {dtype} values; expected numbers (bool, integer or float)")
    if any(not isinstance(s, int) or s < 0 for s in shape):
        raise error(f"{label}: damaged header (shape {shape})")
    need = math.prod(shape) * dtype.itemsize
    if need > MAX_ARRAY_BYTES:
        raise error(f"{label}: shape {shape} would need {need / 2**30:.3g} GiB (more than {MAX_ARRAY_BYTES >> 30} GiB)")
    if need > available - f.tell():
        raise error(f"{label}: cut short or damaged (shape {shape} needs {need} bytes, the file has {max(available - f.tell(), 0)})")


def load_npy(path: Path, label: str, error: type[MocapgraphError]) -> np.ndarray:
    """The array in the ``.npy`` file ``path`` (``label`` names it in errors)."""
    try:
        with open(path, "rb") as f:
            _checked_header(f, os.fstat(f.fileno()).st_size, label, error)
            f.seek(0)
            return np.lib.format.read_array(f, allow_pickle=False)
    except MocapgraphError:
        raise
    except _ARRAY_ERRORS as exc:
        raise error(f"{label}: not a readable .npy file ({type(exc).__name__}: {exc})") from None


def load_npz(path: Path, label: str, error: type[MocapgraphError]) -> dict[str, np.ndarray]:
    """The arrays in the ``.npz`` file ``path`` by name (``label`` names it in errors); every
    member's header is checked against the size the archive declares for it, which bounds the
    bytes zipfile will inflate."""
    arrays = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                name = info.filename.removesuffix(".npy")
                where = f"{label}: {name}"
                if name in arrays:
                    raise error(f"{where}: appears twice in the archive")
                if info.flag_bits & 0x1:  # zipfile would ask for a password (a RuntimeError)
                    raise error(f"{where}: encrypted; arrays must be stored as numpy writes them")
                with archive.open(info) as f:
                    _checked_header(f, info.file_size, where, error)
                with archive.open(info) as f:
                    arrays[name] = np.lib.format.read_array(f, allow_pickle=False)
    except MocapgraphError:
        raise
    except _ARRAY_ERRORS as exc:
        raise error(f"{label}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    return arrays


# ---------------------------------------------------------------------------------------------
# Values


def check_limit(value, where, limit: str | Limit, *, finite_only: bool = False) -> None:
    """Every number of ``value`` (a scalar or array, NaN ignored) lies in ``limit`` (a
    :data:`LIMITS` key or a :class:`Limit`); the message gives the range."""
    lim = LIMITS[limit] if isinstance(limit, str) else limit
    arr = np.asarray(value, dtype=float)
    x = arr[~np.isnan(arr)] if finite_only else arr.ravel()
    low = x <= lim.lo if lim.open_lo else x < lim.lo
    bad = low | (x > lim.hi) | ~np.isfinite(x)
    if np.any(bad):
        raise where.fail(f"{float(x[np.argmax(bad)]):g} is outside {lim.text()}")


def check_number(value, where, limit: str | Limit | None = None, *, integer: bool = False) -> float | int:
    """A TOML/JSON number (never a boolean), finite, an integer when asked, within ``limit``."""
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise where.fail(f"expected {'an integer' if integer else 'a number'}, got {type(value).__name__} {value!r}")
    if not math.isfinite(value):
        raise where.fail(f"must be finite, got {value!r}")
    if limit is not None:
        check_limit(value, where, limit)
    return value


def plain_numbers(value, where) -> None:
    """Refuse booleans and strings in a (nested) TOML/JSON list meant to hold numbers: numpy
    would read ``true`` as 1.0 and ``"3"`` as 3.0."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, (list, tuple)):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float, np.integer, np.floating, np.ndarray)):
            raise where.fail(f"expected numbers, found {type(item).__name__} {item!r}")


def table_list(doc: dict, key: str, where) -> list:
    """``doc[key]``, a list (default empty) of tables, as ``[[key]]`` in TOML."""
    value = doc.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise where(key).fail(f"expected a list of tables ([[{key}]]), got {type(value).__name__}")
    return value


def warn_unknown_keys(table: dict, known: tuple[str, ...], where, *, free_form: bool = False) -> None:
    """Log a warning for each key of ``table`` that is not ``known``, with the nearest known key.

    ``free_form`` tables may hold keys of the user's own (a capture's metadata): only keys that
    look like a misspelt known key are reported there.
    """
    for key in table:
        if key in known:
            continue
        near = difflib.get_close_matches(key, known, n=1, cutoff=0.75)
        if near:
            log.warning("%s: unknown key ignored; did you mean %r?", where(key), near[0])
        elif not free_form:
            log.warning("%s: unknown key ignored (known: %s)", where(key), ", ".join(known))
