"""What every command of the command line shares: argument types, the integrator options, the
early checks of names, output checks, one-line errors and warnings, and the process group under
``torchrun``.

Bad input ends with one line ``invrender: error: ...`` on stderr and exit status 2. This module
imports only the standard library and torch-free modules (:mod:`invrender.cli.catalog`,
:mod:`invrender.errors`): the help texts and the checks of names answer before torch is imported;
everything heavy is imported where a command runs.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from invrender.cli import catalog
from invrender.errors import ImageError, ParameterError, SceneError, did_you_mean

EXIT_BAD_INPUT = 2
#: an unexpected exception (a bug): one line on stderr all the same (INVRENDER_TRACEBACK=1 re-raises it)
EXIT_INTERNAL = 1
EXIT_INTERRUPTED = 130


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``invrender: error: ...``) and exit status 2."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"invrender: error: {message} (see '{self.prog} --help')\n")

    def _check_value(self, action, value):
        # argparse's check of choices (and of the command's name), with the closest one suggested
        if action.choices is not None and value not in action.choices:
            choices = ", ".join(map(str, action.choices))
            if action.dest == "command":
                raise argparse.ArgumentError(None, f"unknown command {value!r}{did_you_mean(value, action.choices)} (the commands: {choices})")
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}{did_you_mean(value, action.choices)} (choose from {choices})")


def parse_bool(text: str) -> bool:
    """``true``/``false`` (also yes/no, 1/0)."""
    value = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}.get(text.strip().lower())
    if value is None:
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return value


def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (width, height), a size a machine can hold (:func:`invrender.validate.check_resolution`)."""
    from invrender.validate import check_resolution

    try:
        w, h = (int(p) for p in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 64x64, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"resolution must be positive, got {text!r}")
    try:
        check_resolution(w, h)
    except ParameterError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return w, h


def parse_device(text: str) -> str:
    """``cpu``, ``cuda`` or ``cuda:N`` (:func:`invrender.validate.check_device`; torch-free)."""
    from invrender.validate import check_device

    try:
        check_device(text)
    except ParameterError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def parse_rgb(text: str) -> list[float]:
    """``"v"`` or ``"r,g,b"`` -> [r, g, b] (finite, >= 0)."""
    values = one_or_three_numbers(text)
    if values is None or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected one number or R,G,B, finite and >= 0, got {text!r}")
    return values * 3 if len(values) == 1 else values


def one_or_three_numbers(text: str) -> list[float] | None:
    """``"v"`` -> [v], ``"r,g,b"`` -> [r, g, b]; None for anything else."""
    try:
        values = [float(p) for p in text.split(",")]
    except ValueError:
        return None
    return values if len(values) in (1, 3) else None


def parse_init(items: list[str]) -> dict:
    """``["NAME=v", "NAME=r,g,b"]`` -> {NAME: value}."""
    init = {}
    for item in items:
        key, sep, text = item.partition("=")
        values = one_or_three_numbers(text)
        if not sep or not key or values is None:
            raise ParameterError(f"--init expects NAME=VALUE or NAME=R,G,B, got {item!r}")
        init[key.strip()] = values[0] if len(values) == 1 else values
    return init


def int_list(text: str, flag: str) -> list[int]:
    """``"1,4,16"`` -> [1, 4, 16]; an empty list is left to the command's own check."""
    try:
        return [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise ParameterError(f"{flag} expects comma-separated integers such as 4,8,16, got {text!r}") from None


def add_scene_argument(parser: argparse.ArgumentParser) -> None:
    """The optional positional SCENE every rendering command takes."""
    parser.add_argument(
        "scene", nargs="?", default="cornell_box",
        help=f"built-in name ({', '.join(catalog.BUILTIN_SCENES)}) or a scene file: .toml, Mitsuba 3 .xml (a subset), or a mesh .gltf/.glb/.obj/.ply/.stl (in a default studio when it has no emitter) (default: cornell_box)",
    )  # fmt: skip


# --- the integrator: --integrator NAME and --set KEY=VALUE ---------------------------------------


def check_names(args) -> None:
    """The names a command was given, checked before anything heavy is imported: its scene (a
    built-in name or an existing scene file) and its ``--integrator``; a one-line error suggesting
    the closest known name otherwise."""
    if getattr(args, "scene", None) is not None:
        check_scene(args.scene)
    if getattr(args, "integrator", None) is not None:
        check_integrator(args.integrator)


def check_scene(source: str) -> None:
    """``source`` names a built-in scene or a scene file that exists (its contents are read by
    :func:`invrender.load_scene`, which words its errors as these)."""
    if source in catalog.BUILTIN_SCENES:
        return
    path = Path(source)
    if path.suffix.lower() not in catalog.SCENE_SUFFIXES:
        raise SceneError(f"unknown scene {source!r}{did_you_mean(source, catalog.BUILTIN_SCENES)}: not a built-in ({', '.join(catalog.BUILTIN_SCENES)}) nor a {'/'.join(catalog.SCENE_SUFFIXES)} file")
    if not path.is_file():
        folder = path.parent if path.parent.is_dir() else None
        files = [p.name for p in folder.iterdir() if p.suffix.lower() in catalog.SCENE_SUFFIXES] if folder is not None else []
        raise SceneError(f"scene file not found: {source}{did_you_mean(path.name, files)}")


def check_integrator(name: str) -> None:
    """``name`` is a built-in integrator or one registered in this process (a plugin)."""
    known = integrator_names()
    if name not in known:
        raise ParameterError(f"--integrator: unknown integrator {name!r}{did_you_mean(name, known)} (known: {', '.join(known)})")


def integrator_names() -> list[str]:
    """The built-in integrators (:mod:`invrender.cli.catalog`) and the plugins registered so far
    in this process, without importing the built-in ones."""
    from invrender.registry import INTEGRATORS

    return list(dict.fromkeys([*catalog.INTEGRATORS, *INTEGRATORS.loaded_names()]))


def add_integrator_arguments(parser: argparse.ArgumentParser, default: str | None = "path", what: str = "the integrator") -> None:
    """``--integrator NAME`` and the repeatable ``--set KEY=VALUE`` (any of its settings; the
    settings of each integrator are listed in the command's help, :func:`integrators_epilog`)."""
    shown = f" (default: {default})" if default else " (default: path, or the recipe's)"
    parser.add_argument("--integrator", default=None, metavar="NAME", help=f"{what}: {', '.join(catalog.INTEGRATORS)}{shown}; its settings are listed below")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", dest="set",
        help="an integrator setting, e.g. --set rr_depth=3 --set strategy=emitter (repeatable; the value is read as the setting's type: int, float, true/false or text)",
    )  # fmt: skip


def integrators_epilog() -> str:
    """The help text listing every built-in integrator with its settings, for ``--integrator``
    and ``--set`` (generated from the registry and the settings dataclasses into
    :mod:`invrender.cli.catalog`)."""
    return "integrators and their settings (--integrator NAME --set KEY=VALUE; all registered: 'invrender plugins'):\n" + catalog.INTEGRATORS_HELP


def integrator_spec(args, base=None, flags: dict | None = None, default: str = "path") -> dict:
    """The integrator spec of a command: ``base`` (a spec, e.g. a recipe's or a scene file's; its
    settings kept when ``--integrator`` names the same integrator or none), then the dedicated
    flags given (``flags``: setting -> value, None = not given), then ``--set KEY=VALUE`` read as
    the settings dataclass's field types say. A setting given twice, differently, is an error."""
    from invrender.registry import integrator_spec as parse
    from invrender.plugins.integrators.base import setting_from_text

    base_name, base_settings = parse(base) if base is not None else (default, {})
    name = args.integrator or base_name
    settings = dict(base_settings) if name == base_name else {}
    given: dict[str, tuple[str, object]] = {}
    for key, value in (flags or {}).items():
        if value is not None:
            given[key] = (f"--{key.replace('_', '-')}", value)
    for item in args.set:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ParameterError(f"--set expects KEY=VALUE (an integrator setting), got {item!r}")
        value = setting_from_text(parse(name, "--integrator")[0], key, text.strip())
        if key in given and given[key][1] != value:
            raise ParameterError(f"{key} is given twice, differently: {given[key][0]} {given[key][1]!r} and --set {item}")
        given[key] = (f"--set {item}", value)
    settings.update({k: v for k, (_, v) in given.items()})
    return {"type": name, **settings}


# --- outputs ------------------------------------------------------------------------------------


def check_outputs(paths: list[str], suffixes: tuple[str, ...] | None = None) -> list[Path]:
    """Fail early (before a long render) on output paths that cannot be written (or whose suffix is
    not one of ``suffixes``, by default the image suffixes)."""
    from invrender.io.images import WRITE_SUFFIXES

    suffixes = suffixes or WRITE_SUFFIXES
    out = []
    for p in paths:
        path = Path(p)
        if path.suffix.lower() not in suffixes:
            raise ImageError(f"cannot write {p}: unknown {'image ' if suffixes == WRITE_SUFFIXES else ''}suffix {path.suffix or '(none)'!r} (use {', '.join(suffixes)})")
        parent = path.parent if str(path.parent) else Path(".")
        existing = next((a for a in [parent, *parent.parents] if a.exists()), Path("."))
        if not existing.is_dir() or not os.access(existing, os.W_OK):
            raise ImageError(f"cannot write {p}: {existing} is not a writable directory")
        if path.is_dir():
            raise ImageError(f"cannot write {p}: it is a directory")
        out.append(path)
    return out


def check_out_dir(text: str) -> Path:
    """An output folder: absent (it is made) or a folder, not a file."""
    out = Path(text)
    if out.exists() and not out.is_dir():
        raise ImageError(f"cannot write to {out}: it is a file")
    return out


def mean_rgb(image) -> str:
    return ", ".join(f"{v:.4g}" for v in image.mean(dim=(0, 1)).tolist())


def fmt(value) -> str:
    flat = value.reshape(-1).tolist()
    return ", ".join(f"{v:.4g}" for v in flat[:6]) + (" ..." if len(flat) > 6 else "")


def say(args, text: str) -> None:
    """A line on stderr, unless ``--quiet``."""
    if not getattr(args, "quiet", False):
        print(text, file=sys.stderr)


def one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"invrender: warning: {message}", file=sys.stderr)


def join_process_group(args) -> str | None:
    """Under ``torchrun`` (docs/scale.md): join the process group, put a CUDA render on this rank's
    GPU, and leave the summaries and progress bars to rank 0 (its outputs are the only ones
    written). Returns the error prefix of this rank (None outside a group)."""
    from invrender.core import ranks

    device = ranks.init_from_environment(getattr(args, "device", None))
    rank, world = ranks.world()
    if world == 1:
        return None
    if device is not None:
        args.device = str(device)
    if rank != 0:
        args.quiet = True
    return f"invrender: error (rank {rank} of {world}): "


def leave_process_group() -> None:
    from invrender.core.ranks import leave_process_group as leave

    leave()  # a group left alive at exit aborts the process (gloo's threads)
