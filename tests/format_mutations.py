"""Damage done to capture and result directories, as an adversarial user or a failing disk would:
structural edits of the TOML manifest, cut or bit-flipped arrays, arrays of odd types and values,
clocks that jump or crawl. Shared by the fuzzer (tests/test_fuzz_formats.py) and the regression
tests of the crashers it found (tests/test_bad_inputs.py).

Every mutation is a plain function of the directory and a ``draw`` (Hypothesis' ``data.draw``),
so a failing example shrinks and prints as the list of what was done.
"""

from __future__ import annotations

import io
import tomllib
import warnings
import zipfile
from pathlib import Path

import numpy as np
import tomli_w
from hypothesis import strategies as st

# Values that break assumptions: wrong types, non-finite and absurd numbers, booleans (an int in
# Python), strings where paths or numbers go, deep or empty containers.
ODD_SCALARS = st.one_of(
    st.sampled_from([0, -1, 1, 2**63 - 1, -(2**63), True, False, 0.0, -0.0, 1.0, 1e-300, 1e300, -1e300, float("nan"), float("inf"), float("-inf")]),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["", ".", "..", "/", "../x", "a\0b", "cam.1", "x" * 300, "cameras", "é", "💥"]),
    st.text(max_size=20),
)
ODD_VALUES = st.recursive(ODD_SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=3)), max_leaves=8)


def _paths(node, prefix=()):
    """Every (path, value) below ``node``: dict keys and list indices."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield prefix + (key,), value
        yield from _paths(value, prefix + (key,))


def _parent(doc, path):
    for key in path[:-1]:
        doc = doc[key]
    return doc


def edit_toml(root: Path, manifest: str, draw) -> str:
    """One structural edit of the manifest's parsed tree: replace, delete, misspell a key, nest."""
    file = root / manifest
    doc = tomllib.loads(file.read_text(encoding="utf-8"))
    paths = [p for p, _ in _paths(doc)]
    if not paths:
        return "toml (nothing to edit)"
    path = draw(st.sampled_from(paths))
    parent, key = _parent(doc, path), path[-1]
    op = draw(st.sampled_from(["replace", "delete", "misspell", "wrap", "duplicate"]))
    if op == "replace":
        parent[key] = draw(ODD_VALUES)
    elif op == "delete":
        del parent[key]
    elif op == "misspell" and isinstance(parent, dict):
        k = draw(st.integers(0, max(len(key) - 1, 0)))
        parent[key[:k] + key[k + 1 :] if key else "x"] = parent.pop(key)
    elif op == "wrap":
        parent[key] = [parent[key]]
    elif isinstance(parent, list):
        parent.append(parent[key])
    try:
        file.write_text(tomli_w.dumps(doc), encoding="utf-8")
    except (TypeError, ValueError):  # tomli_w cannot write every Python value: leave the file as it was
        return f"{op} {path} (not writable as TOML)"
    return f"{op} {path}"


def damage_text(root: Path, manifest: str, draw) -> str:
    """Raw damage to a text file: cut, deep nesting, bytes that are not UTF-8, NUL bytes."""
    file = root / manifest
    data = file.read_bytes()
    op = draw(st.sampled_from(["cut", "deep", "latin1", "nul", "empty", "garbage"]))
    if op == "cut":
        data = data[: draw(st.integers(0, len(data)))]
    elif op == "deep":
        depth = draw(st.integers(100, 5000))
        data += b"\nnested = " + b"[" * depth + b"]" * depth + b"\n"
    elif op == "latin1":
        data = data.replace(b"mocapgraph", "mocapgraph\xe9".encode("latin-1"), 1)
    elif op == "nul":
        at = draw(st.integers(0, len(data)))
        data = data[:at] + b"\0" + data[at:]
    elif op == "empty":
        data = b""
    else:
        data = draw(st.binary(max_size=200))
    file.write_bytes(data)
    return f"{op} {manifest}"


def _npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def huge_header(shape=(10**12, 22, 3), dtype="<f8") -> bytes:
    """An ``.npy`` header claiming ``shape`` over a few bytes of data."""
    header = {"descr": dtype, "fortran_order": False, "shape": shape}
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    return np.lib.format.magic(1, 0) + buf.getvalue()[8:] + b"\0" * 64


def damage_bytes(root: Path, rel: str, draw) -> str:
    """Byte-level damage to an array file: cut, bit flips, empty, header only, the other format,
    a header asking for terabytes."""
    file = root / rel
    data = file.read_bytes()
    op = draw(st.sampled_from(["cut", "flip", "empty", "header", "other_format", "huge", "garbage"]))
    if op == "cut":
        data = data[: draw(st.integers(0, max(len(data) - 1, 0)))]
    elif op == "flip" and data:
        data = bytearray(data)
        for at in draw(st.lists(st.integers(0, len(data) * 8 - 1), min_size=1, max_size=4)):
            data[at // 8] ^= 1 << (at % 8)
        data = bytes(data)
    elif op == "empty":
        data = b""
    elif op == "header":
        data = data[:128]
    elif op == "other_format":
        buf = io.BytesIO()
        np.savez(buf, x=np.zeros(3))
        data = _npy_bytes(np.zeros(3)) if rel.endswith(".npz") else buf.getvalue()
    elif op == "huge":
        data = huge_header()
        if rel.endswith(".npz"):
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w") as z:
                for name in ("keypoints.npy", "t.npy", "timestamps.npy", "joints.npy", "R.npy"):
                    z.writestr(name, data)
            data = buf.getvalue()
    else:
        data = draw(st.binary(max_size=300))
    file.write_bytes(data)
    return f"{op} {rel}"


ODD_DTYPES = st.sampled_from(["f8", "f4", ">f8", "i8", "u1", "bool", "c16", "M8[s]", "m8[ms]", "U3", "S2", "V8", "f8,i4", "O"])


def odd_array(draw, like: np.ndarray) -> np.ndarray:
    """An array near ``like``: another dtype, shape or absurd values."""
    op = draw(st.sampled_from(["dtype", "shape", "values", "empty", "scalar"]))
    if op == "dtype":
        dtype = np.dtype(draw(ODD_DTYPES))
        if dtype.kind == "O":
            return np.array([{"a": 1}] * max(like.size, 1), dtype=object)
        try:
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return like.astype(dtype)
        except (TypeError, ValueError):
            return np.zeros(like.shape, dtype=dtype)
    if op == "shape":
        shape = tuple(draw(st.lists(st.integers(0, 6), min_size=0, max_size=4)))
        return np.ones(shape)
    if op == "values":
        out = np.array(like, dtype=float, copy=True)
        if out.size:
            value = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, 1e9, 1e-12, 0.0, -1.0, 2.0]))
            mask = np.asarray(draw(st.lists(st.booleans(), min_size=out.size, max_size=out.size))).reshape(out.shape)
            out[mask] = value
        return out
    if op == "empty":
        return np.zeros((0,) + like.shape[1:])
    return np.float64(draw(st.floats()))


def edit_array(root: Path, rel: str, draw) -> str:
    """Replace one array (of a ``.npy``, or one member of a ``.npz``) by :func:`odd_array`."""
    file = root / rel
    if rel.endswith(".npy"):
        new = odd_array(draw, np.load(file))
        file.write_bytes(_npy_bytes(new))
        return f"array {rel}: {new.dtype} {new.shape}"
    with np.load(file) as data:
        arrays = {k: data[k] for k in data.files}
    if not arrays:
        return f"array {rel}: empty archive"
    key = draw(st.sampled_from(sorted(arrays)))
    arrays[key] = odd_array(draw, arrays[key])
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    file.write_bytes(buf.getvalue())
    return f"array {rel}[{key}]: {arrays[key].dtype} {arrays[key].shape}"


def edit_clock(root: Path, rel: str, draw) -> str:
    """Odd timestamps: an epoch offset, steps of picoseconds, reversed, repeated, NaN, dates."""
    file = root / rel
    t = np.load(file)
    op = draw(st.sampled_from(["offset", "tiny_steps", "huge_steps", "reverse", "repeat", "nan", "datetime", "structured", "one"]))
    if op == "offset":
        t = t + draw(st.sampled_from([1e9, -1e9, 1e12, 1e300, 3600.0]))
    elif op == "tiny_steps":
        t = t[0] + np.arange(len(t)) * draw(st.sampled_from([1e-12, 1e-9, 1e-7]))
    elif op == "huge_steps":
        t = t[0] + np.arange(len(t)) * draw(st.sampled_from([1e6, 1e9, 1e15]))
    elif op == "reverse":
        t = t[::-1].copy()
    elif op == "repeat":
        t = np.repeat(t[:1], len(t))
    elif op == "nan" and len(t):
        t = t.astype(float)
        t[draw(st.integers(0, len(t) - 1))] = np.nan
    elif op == "datetime":
        t = (t * 1e3).astype("datetime64[ms]")
    elif op == "structured":
        t = np.array([(x, 0) for x in t], dtype=[("t", "f8"), ("i", "i4")])
    else:
        t = t[:1]
    file.write_bytes(_npy_bytes(t))
    return f"clock {rel}: {op}"


def bad_reference(root: Path, manifest: str, draw) -> str:
    """Point a file reference of the manifest at a NUL path, a symlink loop, a directory, outside."""
    file = root / manifest
    doc = tomllib.loads(file.read_text(encoding="utf-8"))
    refs = [p for p, v in _paths(doc) if isinstance(v, str) and v.endswith((".npy", ".npz", ".json"))]
    if not refs:
        return "no file reference"
    path = draw(st.sampled_from(refs))
    op = draw(st.sampled_from(["nul", "loop", "directory", "outside", "absolute", "long"]))
    if op == "loop":
        (root / "loop.npz").symlink_to("loop.npz")
        target = "loop.npz"
    else:
        target = {"nul": "cameras/\0x.npy", "directory": ".", "outside": "../../etc/passwd", "absolute": "/etc/passwd", "long": "a" * 5000}.get(op)
    _parent(doc, path)[path[-1]] = target
    file.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return f"reference {path} -> {op}"


def array_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.suffix in (".npy", ".npz") and not p.is_symlink())


def mutate(root: Path, manifest: str, draw) -> list[str]:
    """One to three mutations of the directory ``root``; returns what was done."""
    done = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["toml", "text", "bytes", "array", "clock", "reference"]))
        arrays = array_files(root)
        clocks = [a for a in arrays if a.endswith("timestamps.npy")]
        if kind == "toml" and (root / manifest).exists():
            try:
                done.append(edit_toml(root, manifest, draw))
            except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError):
                done.append("toml (manifest already unreadable)")
        elif kind == "text" and (root / manifest).exists():
            done.append(damage_text(root, manifest, draw))
        elif kind == "bytes" and arrays:
            done.append(damage_bytes(root, draw(st.sampled_from(arrays)), draw))
        elif kind == "array" and arrays:
            try:
                done.append(edit_array(root, draw(st.sampled_from(arrays)), draw))
            except Exception as exc:  # an array damaged by an earlier mutation cannot be edited: fine
                done.append(f"array (unreadable already: {type(exc).__name__})")
        elif kind == "clock" and clocks:
            try:
                done.append(edit_clock(root, draw(st.sampled_from(clocks)), draw))
            except Exception as exc:
                done.append(f"clock (unreadable already: {type(exc).__name__})")
        elif kind == "reference" and (root / manifest).exists():
            try:
                done.append(bad_reference(root, manifest, draw))
            except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError, FileExistsError, OSError):
                done.append("reference (manifest already unreadable)")
    return done
