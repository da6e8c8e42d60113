"""What every command shares: ``-q``/``-v``, body-model arguments, and flags made from a
pipeline's options dataclass so that each default is written once, in the dataclass."""

from __future__ import annotations

import argparse
import copy
from pathlib import Path


def verbosity_parser() -> argparse.ArgumentParser:
    """The ``-q``/``-v`` every command takes (a parent parser)."""
    parent = argparse.ArgumentParser(add_help=False)
    group = parent.add_argument_group("messages")
    group.add_argument("-q", "--quiet", action="store_const", const=-1, dest="verbosity", help="warnings only, no progress bars")
    group.add_argument("-v", "--verbose", action="count", dest="verbosity", help="more detail (e.g. every solver iteration)")
    parent.set_defaults(verbosity=0)
    return parent


VERBOSITY = verbosity_parser()


def command(subparsers, name: str, help: str, **kw) -> argparse.ArgumentParser:
    """A command's parser with ``-q``/``-v``."""
    return subparsers.add_parser(name, help=help, description=kw.pop("description", help), parents=[VERBOSITY], **kw)


def group(subparsers, name: str, help: str, dest: str):
    """A command group (``run``, ``bench``, …) and its subcommands' subparsers."""
    return subparsers.add_parser(name, help=help, description=help).add_subparsers(dest=dest, required=True, metavar="SUBCOMMAND")


def add_body_args(parser: argparse.ArgumentParser) -> None:
    from mocapgraph.body import BACKENDS

    parser.add_argument("--backend", choices=BACKENDS, default="anny", help="body model (default: anny)")
    parser.add_argument(
        "--model-path", type=Path,
        help="smpl/smplx: your own licensed model file (.npz or .pkl); anny: an exported table (default: the cache)",
    )  # fmt: skip


def body_from(args):
    from mocapgraph.body import load_body_model

    return load_body_model(args.backend, args.model_path)


def result_capture(result, given: Path | None, required: bool = False):
    """The capture a result came from: ``given``, else the one the result names. When that one
    cannot be read, None with a warning (what needs it is left out), or its error if ``required``."""
    import logging

    from mocapgraph.data_tools.io.capture import load_capture
    from mocapgraph.errors import MocapgraphError

    if given is not None or required:
        return load_capture(given if given is not None else result.capture)
    try:
        return load_capture(result.capture)
    except MocapgraphError as exc:
        logging.getLogger(__name__).warning("the result's capture is not readable (%s); pass --capture to use it", exc)
        return None


def result_body(result, model_path: Path | None):
    """The body model a result was solved with, when it can be had: Anny's always, SMPL's from
    ``model_path``; None for a joints-only result or an SMPL result without its model file."""
    from mocapgraph.body import load_body_model

    if not result.has_body_parameters or (result.body_model != "anny" and model_path is None):
        return None
    return load_body_model(result.body_model, model_path)


def detector_list(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected comma-separated detector names")
    return names


def _get(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def _set(obj, path: str, value) -> None:
    *parents, last = path.split(".")
    for part in parents:
        obj = getattr(obj, part)
    setattr(obj, last, value)


class OptionFlags:
    """Command-line flags for fields of an options dataclass, defaults read from ``defaults``.

    ``add("graph.gm_sigma_px", "…")`` adds ``--gm-sigma-px`` whose default is
    ``defaults.graph.gm_sigma_px``; a bool field becomes ``--no-<name>`` (default True) or
    ``--<name>`` (default False); :meth:`build` returns a copy of ``defaults`` with the parsed
    values set.
    """

    def __init__(self, parser: argparse.ArgumentParser, defaults):
        self.parser, self.defaults = parser, defaults
        self.fields: list[tuple[str, str]] = []
        parser.set_defaults(options_from=self.build)

    def add(self, path: str, help: str, *, flag: str | None = None, unset: str = "none", **kw) -> None:
        """A flag for the field at ``path`` (dotted for nested options); ``unset`` says what a
        default of None means in the help."""
        default = _get(self.defaults, path)
        dest = "option__" + path.replace(".", "__")
        name = path.split(".")[-1]
        if isinstance(default, bool):
            flag = flag or (f"--no-{name}" if default else f"--{name}").replace("_", "-")
            self.parser.add_argument(flag, dest=dest, action="store_false" if default else "store_true", help=help)
        else:
            shown = unset if default is None else ",".join(default) if isinstance(default, tuple) else default
            if "type" not in kw and default is not None and not isinstance(default, tuple):
                kw["type"] = type(default)
            kw.setdefault("metavar", None if "choices" in kw else name.upper())
            self.parser.add_argument(flag or "--" + name.replace("_", "-"), dest=dest, default=default, help=f"{help} (default: {shown})", **kw)
        self.fields.append((path, dest))

    def build(self, args):
        options = copy.deepcopy(self.defaults)
        for path, dest in self.fields:
            _set(options, path, getattr(args, dest))
        return options


def out_args(parser: argparse.ArgumentParser, what: str = "result") -> None:
    parser.add_argument("--out", type=Path, required=True, help=f"{what} directory to write")
    parser.add_argument("--overwrite", action="store_true", help=f"replace an existing {what}")



def function_flags(parser: argparse.ArgumentParser, fn, params: dict[str, str | tuple[str, dict]]) -> list[str]:
    """Flags for keyword parameters of ``fn`` with its defaults (read from its signature):
    ``params`` maps a parameter to its help, or to ``(help, add_argument keywords)`` where a
    ``flag`` keyword renames the flag. Returns the parameter names (the ``dest`` of each flag)."""
    import inspect

    signature = inspect.signature(fn).parameters
    for name, spec in params.items():
        help, kw = (spec, {}) if isinstance(spec, str) else (spec[0], dict(spec[1]))
        flag = kw.pop("flag", "--" + name.replace("_", "-"))
        default = signature[name].default
        if default is inspect.Parameter.empty:  # a required argument with a default of its own here (e.g. the motion directory)
            default = None
        if "type" not in kw and default is not None:
            kw["type"] = type(default)
        shown = "" if default is None else f" (default: {default:g})" if isinstance(default, float) else f" (default: {default})"
        parser.add_argument(flag, dest=name, default=default, help=help + shown, **kw)
    return list(params)
