"""The command lines' flags of study settings come from the defaults table (scripts/_cli_flags.py).

Every flag of a study setting in ``pdehead.py`` and ``pdehead_batch.py run`` (and the loader options they
share) is declared by ``_cli_flags.add``: its default, type, choices and range are the table's, with today's
names; a flag written by hand for a setting of the table fails here. In process, no Blender: argument parsing
only.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import _cli_flags  # noqa: E402
import pdehead  # noqa: E402
import pdehead_batch  # noqa: E402

D = _cli_flags.defaults()

#: The flags that are no study setting (outputs, modes, inputs, the loader's raw description); a new flag
#: must be added here or be generated.
HAND_WRITTEN = {
    "pdehead": {"-h", "--help", "--phantom", "--no-volume", "--out", "--render", "--render-volume", "--summary-json",
                "--skull", "--export", "--skull-mesh", "--face-from-skull", "--depth-table", "--sex",
                "--render-animation", "--format", "--raw-shape", "--dtype", "--spacing", "--first-slice",
                "--orientation", "--units", "--series-uid"},
    "batch": {"-h", "--help", "--out", "--workers", "--scheduler", "--skull", "--time-limit", "--memory-limit",
              "--force", "--summary-json", "--format", "--raw-shape", "--dtype", "--spacing", "--first-slice",
              "--orientation", "--units", "--series-uid"},
}


def batch_run_parser() -> argparse.ArgumentParser:
    """The ``run`` subcommand's parser of pdehead_batch.py."""
    return pdehead_batch.parsers()[1]


PARSERS = {"pdehead": pdehead._parser, "batch": batch_run_parser}
BASE = {"pdehead": ["--phantom"], "batch": ["run", "x", "--out", "o"]}


def parse(which: str, *extra):
    """(namespace, None) or (None, the usage error's message) of one command line."""
    argv = [*BASE[which], *map(str, extra)]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            if which == "pdehead":
                return pdehead.parse_args(argv), None
            return pdehead_batch.parse_args(argv), None
    except SystemExit as exc:
        assert exc.code == 2, err.getvalue()
        return None, err.getvalue().strip().splitlines()[-1]
    except pdehead_batch.CLIError as exc:   # the batch's usage errors (its main prints them, exit 2)
        return None, str(exc)


def settings_flags(which: str) -> list[argparse.Action]:
    return _cli_flags.generated(PARSERS[which]())


@pytest.mark.parametrize("which", sorted(PARSERS))
def test_no_flag_of_a_study_setting_is_hand_written(which):
    """Every option is generated from the table or a listed non-setting; none of the hand-written ones is named
    after a setting of the table."""
    parser = PARSERS[which]()
    generated = {a.option_strings[0] for a in _cli_flags.generated(parser)}
    options = {o for a in parser._actions for o in a.option_strings}
    hand = options - generated
    assert hand == HAND_WRITTEN[which], (f"hand-written flags {sorted(hand - HAND_WRITTEN[which])}: declare a study "
                                         f"setting's flag with _cli_flags.add, list other flags in HAND_WRITTEN")
    for action in parser._actions:
        if action.option_strings and action.option_strings[0] in hand:
            name = action.option_strings[-1].lstrip("-").replace("-", "_")
            if name in _cli_flags.HAND_WRITTEN:
                continue
            assert name not in D.PARAMS and action.dest not in D.PARAMS, \
                f"{action.option_strings[0]} is the study setting {name!r}: generate it (_cli_flags.add)"
    # today's names, one per setting, each a setting of the table
    assert set(_cli_flags.CLI_FLAGS) <= set(D.PARAMS)
    assert len({f.cli_flag for f in _cli_flags.CLI_FLAGS.values()}) == len(_cli_flags.CLI_FLAGS)


def test_every_table_entry_is_a_flag_of_a_command_line_with_todays_name():
    used = {getattr(a, _cli_flags.SETTING_ATTRIBUTE) for which in PARSERS for a in settings_flags(which)}
    assert used == set(_cli_flags.CLI_FLAGS)
    assert {s: f.cli_flag for s, f in _cli_flags.CLI_FLAGS.items()} == {
        "patches": "--patches", "samples": "--samples", "tolerance_mm": "--tolerance",
        "max_tolerance_mm": "--max-tolerance", "selection": "--selection", "align_curves": "--no-align",
        "nu": "--nu", "nv": "--nv", "detail_strength": "--detail", "nw": "--nw", "voxel_size": "--voxel-size",
        "view": "--view", "resolution": "--resolution", "render_samples": "--render-samples",
        "turntable_frames": "--turntable", "export_format": "--export-format", "bone_level": "--bone-level",
        "downsample": "--downsample"}


def _cases():
    for which in sorted(PARSERS):
        for action in settings_flags(which):
            yield pytest.param(which, action.option_strings[0], getattr(action, _cli_flags.SETTING_ATTRIBUTE),
                               id=f"{which}{action.option_strings[0]}")


@pytest.mark.parametrize("which, flag, setting", list(_cases()))
def test_a_settings_flag_has_the_tables_default_and_range(which, flag, setting):
    param = D.PARAMS[setting]
    spec = _cli_flags.CLI_FLAGS[setting]
    action = next(a for a in settings_flags(which) if a.option_strings[0] == flag)
    args, error = parse(which)
    assert error is None, error
    value = getattr(args, action.dest)
    if spec.negates:                 # --no-align: off, the setting on (its default)
        assert value is False and param.default is True
        assert getattr(parse(which, flag)[0], action.dest) is True
        return
    if spec.absent:                  # left out: the setting's companion is off / automatic (said in the help)
        assert value is None and f"default: {spec.absent}" in action.help.replace("%%", "%")
    else:                            # left out: the table's default (also where the script tells given from not)
        assert value == param.default and type(value) is type(param.default)
    if param.choices:
        assert list(action.choices) == list(param.choices)
        for choice in param.choices:
            assert getattr(parse(which, flag, choice)[0], action.dest) == choice
        _, error = parse(which, flag, "not-a-choice")
        assert error is not None and flag in error and "invalid choice" in error
        return
    assert action.type is type(param.default)
    assert _cli_flags.range_text(param, spec.positive) in action.help
    if param.unit:
        assert param.unit in action.help
    extra = ["--skull"] if setting == "bone_level" else []
    for bound, beyond in ((param.min, -1), (param.max, +1)):
        if bound is None:
            continue
        if not (spec.positive and beyond < 0):        # the bound itself is accepted (not a positive flag's 0)
            args, error = parse(which, *extra, flag, bound)
            assert error is None and getattr(args, action.dest) == bound, error
        outside = bound + beyond if isinstance(param.default, int) else bound + beyond * 0.5
        args, error = parse(which, *extra, flag, outside)
        assert args is None and error is not None and flag in error, (flag, outside, error)


def test_the_range_errors_read_as_before():
    """The messages users and tests know (exit 2, naming the flag)."""
    assert parse("pdehead", "--patches", 0)[1] == "pdehead: error: --patches must be at least 1, got 0"
    assert parse("pdehead", "--detail", -1)[1] == "pdehead: error: --detail must be at least 0, got -1.0"
    assert parse("pdehead", "--tolerance", 0)[1] == "pdehead: error: --tolerance must be a distance > 0 mm, got 0.0"
    assert parse("pdehead", "--downsample", 9)[1] == "pdehead: error: --downsample must be at most 8, got 9"
    assert parse("batch", "--patches", 0)[1] == "--patches must be at least 1, got 0"
    assert "invalid choice" in parse("pdehead", "--export-format", "fbx")[1]
