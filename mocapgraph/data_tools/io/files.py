"""Reading and writing the directories of captures and results: validation that names the file
and the field, and writes that never leave a half-written directory in place of a good one."""

from __future__ import annotations

import fcntl
import glob
import logging
import os
import shutil
import signal
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mocapgraph.data_tools.io.checks import LIMITS, check_limit, load_npy, load_npz, parse_toml, plain_numbers, read_text, resolve_inside
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)


class Where:
    """A place in a data directory for error messages: ``file: field``.

    ``error`` is the exception type raised for this directory kind (CaptureError, ResultError).
    """

    def __init__(self, file: str, field: str = "", error: type[MocapgraphError] = MocapgraphError):
        self.file, self.field, self.error = file, field, error

    def __call__(self, sub: str) -> Where:
        return Where(self.file, f"{self.field}.{sub}" if self.field else sub, self.error)

    def at(self, file: str, field: str = "") -> Where:
        """Another file of the same directory."""
        return Where(file, field, self.error)

    def __str__(self) -> str:
        return f"{self.file}: {self.field}" if self.field else self.file

    def fail(self, message: str) -> MocapgraphError:
        return self.error(f"{self}: {message}")


def read_manifest(
    path: str | Path, manifest: str, format_name: str, version: int, error: type[MocapgraphError]
) -> tuple[Path, dict, Where]:
    """Open a data directory (or its manifest file): its root, the parsed TOML, and a ``Where``.

    Checks that the directory and manifest exist and that ``format`` and ``version`` are the ones
    this reader knows.
    """
    path = Path(path)
    root = path.parent if path.name == manifest else path
    manifest_path = root / manifest
    try:
        if not root.exists():
            raise error(f"{root}: directory not found")
        if not manifest_path.is_file():
            raise error(f"{manifest_path}: missing (a {format_name} is a directory with a {manifest} manifest)")
    except (OSError, ValueError) as exc:  # NUL bytes, symlink loops, names too long
        raise error(f"{root}: cannot be used as a {format_name} directory ({exc})") from None
    doc = parse_toml(read_text(manifest_path, error, "a TOML manifest"), manifest_path, error)
    where = Where(manifest, error=error)
    if doc.get("format") != format_name:
        raise where("format").fail(f"expected {format_name!r}, got {doc.get('format')!r}")
    found = doc.get("version")
    if type(found) is not int or found != version:  # 1.0 and true compare equal to 1
        raise where("version").fail(f"this mocapgraph reads version {version} (an integer), the file says {found!r}")
    return root, doc, where


def check_array(
    value, where: Where, shape: tuple[int | None, ...], *, allow_nan: bool = False, limit: str | None = None
) -> np.ndarray:
    """``value`` as a float array of ``shape`` (None = any), finite (NaN allowed if asked), every
    number within ``limit`` (a key of :data:`~mocapgraph.data_tools.io.checks.LIMITS`) if given.
    Booleans are refused: they are not numbers, though numpy would read them as 0 and 1."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "iuf":
            raise where.fail(f"expected numbers, got {value.dtype} values")
    else:
        plain_numbers(value, where)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise where.fail("not a numeric array") from None
    if arr.ndim != len(shape) or any(s is not None and s != g for s, g in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise where.fail(f"expected shape {want}, got {arr.shape}")
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if np.any(bad):
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise where.fail(f"contains {'inf' if allow_nan else 'NaN or inf'} (first at {first})")
    if limit is not None:
        check_limit(arr, where, limit, finite_only=allow_nan)
    return arr


def check_rotations(R: np.ndarray, where: Where) -> None:
    """Every ``(…, 3, 3)`` block is a proper rotation to 1e-6."""
    with np.errstate(over="ignore", invalid="ignore"):  # entries of 1e300 are refused below, not warned about
        err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(initial=0.0)
        flipped = np.any(np.linalg.det(R) < 0)
    if not err <= 1e-6 or flipped:
        raise where.fail(f"not a rotation matrix (orthonormality error {err:.2g})")


def check_increasing(t: np.ndarray, where: Where) -> None:
    """A non-empty, strictly increasing time axis of seconds, its samples at least
    ``LIMITS["time_step"].lo`` apart and spanning at most ``LIMITS["time_span"].hi``: a time grid
    over such an axis stays of a size that fits in memory."""
    if t.size == 0:
        raise where.fail("is empty")
    check_limit(t, where, "time")
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        # float(): NumPy 2 scalars repr as "np.float64(0.1)"
        raise where.fail(f"must be strictly increasing (index {i + 1}: {float(t[i + 1])!r} after {float(t[i])!r})")
    step, span = LIMITS["time_step"], LIMITS["time_span"]
    if np.any(steps < step.lo):
        i = int(np.argmax(steps < step.lo))
        raise where.fail(f"samples {i} and {i + 1} are {float(steps[i]):.3g} s apart; at least {step.lo:g} s expected")
    if t[-1] - t[0] > span.hi:
        raise where.fail(f"spans {float(t[-1] - t[0]):.4g} s, more than {span.hi:g} s")


def require_key(table: dict, key: str, where: Where, kind=None):
    """``table[key]``, which must exist (and be an instance of ``kind`` if given)."""
    if key not in table:
        raise where(key).fail("missing")
    value = table[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if kind is not None and (not isinstance(value, kind) or (isinstance(value, bool) and bool not in kinds)):
        raise where(key).fail(f"expected {' or '.join(k.__name__ for k in kinds)}, got {type(value).__name__}")
    return value


class ArrayFiles:
    """Reads ``.npy`` / ``.npz`` files under a directory, naming them in every error."""

    def __init__(self, root: Path, error: type[MocapgraphError]):
        self.root, self.error = root, error

    def resolve(self, rel: str, where: Where) -> Path:
        return resolve_inside(self.root, rel, where)

    def npy(self, rel: str, where: Where) -> np.ndarray:
        return load_npy(self.resolve(rel, where), rel, self.error)

    def npz(self, rel: str, where: Where, required: tuple[str, ...]) -> dict[str, np.ndarray]:
        arrays = load_npz(self.resolve(rel, where), rel, self.error)
        for key in required:
            if key not in arrays:
                have = ", ".join(sorted(arrays)) or "nothing"
                raise self.error(f"{rel}: {key}: missing (the file has {have})")
        return arrays


def write_manifest(path: Path, kind: str, doc_page: str, doc: dict) -> None:
    """Write a TOML manifest headed by a comment naming its documentation and pose convention."""
    import tomli_w

    path.write_text(
        f"# mocapgraph {kind}; fields are documented in {doc_page}.\n"
        "# Camera poses in files are R, t world->camera (x_cam = R x_world + t), as in OpenCV.\n"
        + tomli_w.dumps(doc),
        encoding="utf-8",
    )


def refuse_existing(path: Path, overwrite: bool, error: type[MocapgraphError] = MocapgraphError) -> None:
    """Raise ``error`` when ``path`` exists and may not be replaced: callers check before a long
    run, so a user learns it before waiting for the run, not after."""
    if path.exists() and not overwrite:
        raise error(f"{path}: already exists (pass overwrite=True / --overwrite to replace it)")


# ---------------------------------------------------------------------------------------------
# Output directories: reserved before the work, replaced so that a kill leaves the old or the new.
#
# A write of OUT holds ``.OUT.lock`` (an flock, released by the kernel when the process dies)
# from the reservation to the end of the write. Under it, the write goes to ``.OUT.tmp-*``; a
# replace moves the old OUT to ``.OUT.old-PID``, the new one into place, then deletes the old.
# The next reservation of OUT repairs what a kill can leave: OUT missing with ``.OUT.old-*``
# (killed between the two renames) is restored, stale ``.OUT.tmp-*`` / ``.OUT.old-*`` deleted.

_HELD: dict[Path, tuple[int, Path]] = {}
"""Reservations this process holds: resolved OUT → (lock file descriptor, lock path)."""

KILL_AT_ENV = "MOCAPGRAPH_KILL_AT"
"""Tests set it to a step of :func:`write_directory_atomically` (``written``, ``old-aside``,
``new-in-place``) to SIGKILL the writing process exactly there."""


def _kill_point(step: str) -> None:
    if os.environ.get(KILL_AT_ENV) == step:
        os.kill(os.getpid(), signal.SIGKILL)


def _siblings(path: Path, kind: str) -> list[Path]:
    """``.NAME.<kind>-*`` next to ``path``, oldest first."""
    found = path.parent.glob(f".{glob.escape(path.name)}.{kind}-*")
    return sorted(found, key=lambda p: p.lstat().st_mtime)


def _recover(path: Path) -> None:
    """Undo what a killed write of ``path`` left (call with its lock held)."""
    olds = _siblings(path, "old")
    if olds and not os.path.lexists(path):
        previous = olds.pop()
        os.replace(previous, path)
        log.warning("%s: missing after an interrupted replace; restored its previous version from %s", path, previous.name)
    for stale in olds + _siblings(path, "tmp"):
        shutil.rmtree(stale, ignore_errors=True)


def _lock(path: Path, error: type[MocapgraphError]) -> tuple[int, Path]:
    lock = path.parent / f".{path.name}.lock"
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise error(f"{path}: another mocapgraph process (pid {holder}) is writing it; wait for it, or write elsewhere") from None
        try:
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:  # not a lock file its last holder just unlinked
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd, lock


def _check_replaceable(path: Path, overwrite: bool, replaces: str, error: type[MocapgraphError]) -> None:
    """``path`` may be written: it does not exist, or ``overwrite`` and it is an empty directory
    or a mocapgraph directory (one holding the manifest ``replaces``)."""
    if not os.path.lexists(path):
        return
    kind = "result" if replaces == "result.toml" else "capture" if replaces == "capture.toml" else f"directory with {replaces}"
    if not overwrite:
        raise error(f"{path}: already exists (pass --overwrite to replace it)")
    if path.is_symlink() or not path.is_dir():
        raise error(f"{path}: not a directory; --overwrite only replaces a mocapgraph {kind} (remove it yourself if it must go)")
    if any(path.iterdir()) and not (path / replaces).is_file():
        raise error(f"{path}: not a mocapgraph {kind} (no {replaces}); --overwrite only replaces those (remove it yourself if it must go)")


def reserve_output(
    path: str | Path, overwrite: bool, replaces: str, *, inputs=(), error: type[MocapgraphError] = MocapgraphError
) -> Path:
    """Check and reserve the output directory ``path`` before any work, or raise ``error``.

    ``replaces`` is the manifest that marks a directory ``overwrite`` may replace
    (``result.toml``, ``capture.toml``); ``inputs`` are the command's input paths, which ``path``
    must neither be nor contain. The folder is created, a lock taken (another process writing
    ``path`` is refused) and what a killed earlier write left is repaired. The reservation lasts
    until :func:`release_output` (which :func:`write_directory_atomically` calls when done).
    """
    path = Path(path)
    try:
        key = path.resolve()
        if key in _HELD:
            return path
        for given in inputs:
            source = Path(given).resolve()
            if key == source or key in source.parents:
                raise error(f"{path}: is {'the' if key == source else 'a folder around the'} command's input {given}; write the output elsewhere")
        if len(path.name.encode()) > 200:  # its .NAME.tmp-XXXXXXXX sibling must fit in 255 bytes too
            raise error(f"{path}: name too long ({len(path.name.encode())} bytes; at most 200)")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except FileExistsError:  # a file where the folder should be: said below
            pass
        if not path.parent.is_dir():
            raise error(f"{path}: cannot be written ({path.parent} is not a directory)")
        fd, lock = _lock(path, error)
    except OSError as exc:
        raise error(f"{path}: cannot be written ({exc.strerror or exc})") from None
    except ValueError as exc:  # a NUL byte in the path
        raise error(f"{path}: cannot be written ({exc})") from None
    _HELD[key] = (fd, lock)
    try:
        _recover(path)
        _check_replaceable(path, overwrite, replaces, error)
    except BaseException:
        release_output(path)
        raise
    return path


def release_output(path: str | Path) -> None:
    """End the reservation of ``path`` (nothing when this process holds none)."""
    held = _HELD.pop(Path(path).resolve(), None)
    if held is not None:
        fd, lock = held
        Path(lock).unlink(missing_ok=True)
        os.close(fd)


def release_outputs() -> None:
    """End every reservation this process holds (a command that failed before writing)."""
    for key in list(_HELD):
        release_output(key)


def write_directory_atomically(
    path: Path,
    overwrite: bool,
    write: Callable[[Path], None],
    validate: Callable[[Path], object],
    error: type[MocapgraphError],
    *,
    replaces: str,
) -> Path:
    """Run ``write(tmp)`` into a temporary sibling of ``path``, ``validate(tmp)``, then swap it in.

    ``path`` is reserved as by :func:`reserve_output` (unless this process already holds it) and
    released when written. On any failure the temporary directory is removed and whatever was at
    ``path`` stays; a kill at any instant leaves the old directory or the new one (or the old one
    at ``.NAME.old-PID``, put back by the next reservation).
    """
    path = Path(path)
    reserve_output(path, overwrite, replaces, error=error)
    try:
        _write_and_swap(path, overwrite, write, validate, error, replaces)
    finally:
        release_output(path)
    return path


def _write_and_swap(path: Path, overwrite: bool, write, validate, error: type[MocapgraphError], replaces: str) -> None:
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    except OSError as exc:
        raise error(f"{path}: cannot be written ({exc.strerror or exc})") from None
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; the result is an ordinary directory
    try:
        write(tmp)
        validate(tmp)  # never move an unreadable directory into place
        _kill_point("written")
        if os.path.lexists(path):
            _check_replaceable(path, overwrite, replaces, error)  # it may have appeared during the run
            old = path.with_name(f".{path.name}.old-{os.getpid()}")
            os.replace(path, old)
            _kill_point("old-aside")
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old, path)
                raise
            _kill_point("new-in-place")
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise error(f"{path}: cannot be written ({exc.strerror or exc})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_file_atomically(
    path: Path, overwrite: bool, write: Callable[[Path], None], error: type[MocapgraphError] = MocapgraphError
) -> Path:
    """Run ``write(tmp)`` into a temporary sibling of ``path`` (same suffix), then rename it over ``path``.

    On any failure the temporary file is removed and whatever was at ``path`` stays.
    """
    path = Path(path)
    refuse_existing(path, overwrite, error)
    if path.is_dir():
        raise error(f"{path}: is a directory; name a file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp-", suffix=path.suffix, dir=path.parent)
    except (OSError, ValueError) as exc:
        raise error(f"{path}: cannot be written ({getattr(exc, 'strerror', None) or exc})") from None
    os.close(fd)
    try:
        write(Path(tmp))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; the export is an ordinary file
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise error(f"{path}: cannot be written ({exc.strerror or exc})") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
