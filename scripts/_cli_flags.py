"""The command lines' flags of study settings, generated from the one defaults table.

Each study setting is declared once in ``pdehead_addon/defaults.py`` (default, range, choices, unit,
description); ``operators/study/props.py``'s ``SETTINGS`` adds what Blender needs, and :data:`CLI_FLAGS` here adds
what a command line needs: the flag's name (``cli_flag``, kept as users know it, e.g. ``--tolerance`` for
``tolerance_mm``), its wording in the CLI's terms and how its absence reads. :func:`add` declares the argparse
flag with the table's default, type, choices and a help text naming the range, unit and default;
:func:`check` reports a value outside the table's range as a usage error naming the flag. Flags that are no
study setting (``--export``, ``--summary-json``, the loader's ``--raw-shape`` ...) stay hand-written in the
scripts (``pdehead.py``, ``pdehead_batch.py``, ``_common.py``).

Plain Python (argparse and the defaults table, no bpy, no engine): the scripts parse their arguments before
Blender is loaded.
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def defaults():
    """``pdehead_addon/defaults.py`` (plain Python: loaded without the engine's heavy imports)."""
    name = "pdehead_addon.defaults"
    module = sys.modules.get(name) or sys.modules.get("_pdehead_defaults")
    if module is None:
        spec = importlib.util.spec_from_file_location("_pdehead_defaults", ROOT / "pdehead_addon" / "defaults.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules["_pdehead_defaults"] = module  # dataclasses look their module up while building
        spec.loader.exec_module(module)
    return module


#: The attribute an argparse action generated here carries: the name of its study setting.
SETTING_ATTRIBUTE = "pdehead_setting"


@dataclass(frozen=True)
class CliFlag:
    """What a command line adds to one setting of the defaults table.

    Parameters
    ----------
    cli_flag : str
        The option string (today's name, which need not be the setting's: ``--tolerance``).
    text : str
        What the flag does, in the CLI's words; the range, unit and default are appended. Empty: the
        setting's description.
    metavar : str, optional
        The value's name in ``--help``.
    absent : str, optional
        What leaving the flag out means when that is not the setting's default (``--detail``: no detail
        layer); the argparse default is then None.
    negates : bool
        A switch that turns a setting that is on by default off (``--no-align`` for ``align_curves``).
    positive : bool
        The value must be above the range's minimum (the script says so; the help shows it).
    """

    cli_flag: str
    text: str = ""
    metavar: str | None = None
    absent: str | None = None
    negates: bool = False
    positive: bool = False

    @property
    def dest(self) -> str:
        return self.cli_flag.lstrip("-").replace("-", "_")


#: The study settings the command lines expose, by setting name (``pdehead_addon/defaults.py``'s ``PARAMS``).
CLI_FLAGS: dict[str, CliFlag] = {
    # the boundary curves
    "patches": CliFlag("--patches", "PDE patches t (3t+1 boundary curves)"),
    "samples": CliFlag("--samples", "points per boundary curve"),
    "tolerance_mm": CliFlag(
        "--tolerance", "instead of --patches: the fewest curves whose surface keeps a mean distance of at most MM "
                       "from every slice's outline (automatic selection)",
        metavar="MM", absent="none (--patches sets the number of curves)", positive=True),
    "max_tolerance_mm": CliFlag(
        "--max-tolerance", "with --tolerance (or alone): also bound the largest distance from the outlines",
        metavar="MM", absent="no bound", positive=True),
    "selection": CliFlag("--selection", "how the 3t+1 slices are chosen (shape-change: denser where the face "
                                        "changes; auto: closest to every slice's outline)"),
    "align_curves": CliFlag("--no-align", "keep the curves uniform in arc length (no correspondence alignment)",
                            negates=True),
    # surface, detail, solid, volume
    "nu": CliFlag("--nu", "surface/solid resolution along u"),
    "nv": CliFlag("--nv", "surface/solid resolution around v"),
    "detail_strength": CliFlag(
        "--detail", "build the CT detail layer (the CT's skin as a displacement of the PDE surface along its "
                    "normals: eyelids, lips, nostrils) and apply it at STRENGTH (0 = the PDE surface, 1 = the "
                    "CT's detail) to the surface and to skin.<fmt> of --export",
        metavar="STRENGTH", absent="no detail layer"),
    "nw": CliFlag("--nw", "solid levels in w"),
    "voxel_size": CliFlag("--voxel-size", "volume voxel size",
                          absent="automatic from the CT spacing within the .vdb and w-field budgets, as in the add-on"),
    # renders
    "view": CliFlag("--view", "render view (FRONT: the face, patient left on screen right)"),
    "resolution": CliFlag("--resolution", "render size in pixels"),
    "render_samples": CliFlag("--render-samples", "Cycles samples"),
    "turntable_frames": CliFlag("--turntable", "a camera orbit of N frames around the head (frames 1..N)",
                                metavar="N", absent="no animation"),
    # forensic
    "export_format": CliFlag("--export-format", "mesh format"),
    "bone_level": CliFlag(
        "--bone-level", "bone level in the scan's stored units (HU where calibrated); from it on the skull is the "
                        "bone mask alone",
        metavar="VALUE", absent="the documented rule (HU scans: half way between the soft-tissue and bone modes, "
                               "400 HU without them; uncalibrated scans without soft tissue: half way between the "
                               "air and bone modes)"),
    # import
    "downsample": CliFlag("--downsample", "average N x N x N voxel blocks on import (very large scans: 2 needs "
                                          "1/8 of the memory)", metavar="N"),
}

#: Settings of the table whose command-line flag is written by hand on purpose, and why.
HAND_WRITTEN = {
    "raw_shape": "--raw-shape has no default: raw input must give its shape (the import dialog's default is "
                 "CThead's; defaults.py RAW_SHAPE)",
}


def _number(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def range_text(param, positive: bool = False) -> str:
    """The range of ``param`` in words with its unit ("1 to 60", "0 to 20 mm", "at least 16 px"); "" without one."""
    unit = f" {param.unit}" if param.unit else ""
    low = None if param.min is None else ("above " if positive else "") + _number(param.min)
    if low is not None and param.max is not None:
        return f"{low} to {_number(param.max)}{unit}"
    if low is not None:
        return f"{low}{unit}" if positive else f"at least {low}{unit}"
    if param.max is not None:
        return f"at most {_number(param.max)}{unit}"
    return ""


def help_text(setting: str, spec: CliFlag | None = None) -> str:
    """The ``--help`` line of a setting's flag: what it does, its range (or choices) with the unit, its default."""
    param = defaults().PARAMS[setting]
    spec = spec or CLI_FLAGS[setting]
    parts = [spec.text or param.description]
    if spec.negates:
        parts.append(f"default: off ({setting.replace('_', ' ')} on)")
    else:
        if not param.choices:
            parts.append(range_text(param, spec.positive))
        unit = f" {param.unit}" if param.unit and not param.choices else ""
        parts.append(f"default: {spec.absent}" if spec.absent else f"default {_number(param.default)}{unit}")
    return "; ".join(p for p in parts if p).replace("%", "%%")


def add(parser, setting: str, *, given: bool = False) -> argparse.Action:
    """Declare the flag of ``setting`` (:data:`CLI_FLAGS`) on ``parser`` (a parser or an argument group).

    The default, type and choices are the defaults table's; ``given``: the argparse default is None so that
    the script can tell whether the flag was given (it applies the table's default itself). The action
    carries the setting's name (:data:`SETTING_ATTRIBUTE`) for :func:`check` and the tests.
    """
    param = defaults().PARAMS[setting]
    spec = CLI_FLAGS[setting]
    kwargs: dict = {"help": help_text(setting, spec)}
    if spec.negates:
        if param.default is not True:
            raise ValueError(f"{spec.cli_flag} negates {setting}, whose default is not on")
        kwargs["action"] = "store_true"
    else:
        if isinstance(param.default, (bool, tuple)):
            raise ValueError(f"{setting}: no command-line flag for a {type(param.default).__name__} setting")
        if param.choices:
            kwargs["choices"] = list(param.choices)
        else:
            kwargs["type"] = type(param.default)
        kwargs["default"] = None if (given or spec.absent) else param.default
        if spec.metavar:
            kwargs["metavar"] = spec.metavar
    action = parser.add_argument(spec.cli_flag, **kwargs)
    setattr(action, SETTING_ATTRIBUTE, setting)
    return action


def generated(parser) -> list[argparse.Action]:
    """The actions of ``parser`` that :func:`add` declared."""
    return [a for a in parser._actions if getattr(a, SETTING_ATTRIBUTE, None)]


def check(parser, args, error) -> None:
    """Every given value of a generated flag within its setting's range: else ``error(message)`` (a usage
    error, exit 2; it must not return) with the table's message naming the flag (``--patches must be at least
    1, got 0``). Choices are argparse's; the ``positive`` rule is the script's (its own message)."""
    params = defaults().PARAMS
    for action in generated(parser):
        value = getattr(args, action.dest, None)
        if value is None or isinstance(value, bool):
            continue
        try:
            params[getattr(action, SETTING_ATTRIBUTE)].check(value, action.option_strings[0])
        except ValueError as exc:
            error(str(exc))
