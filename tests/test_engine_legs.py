"""The split of the real-head engine modules between .ci/run's main and 5.3 legs (tests/engine_legs.py)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from engine_legs import ENGINE_LEGS, ONE_ENGINE_LEG, runs_on

ROOT = Path(__file__).resolve().parents[1]


def test_every_listed_module_is_an_engine_test_module_given_to_a_leg():
    assert ONE_ENGINE_LEG
    for module, leg in ONE_ENGINE_LEG.items():
        path = ROOT / module
        assert path.is_file() and path.name.startswith("test_"), f"{module}: no such test module"
        assert "blender" not in Path(module).parts, f"{module}: Blender tests run on every leg"
        assert leg in ENGINE_LEGS, f"{module}: {leg!r} is not an engine leg"


def test_each_leg_builds_a_face_from_a_real_skull_and_finds_its_landmarks():
    """Both numpy versions still build CThead's face and find its landmarks: each half holds such a module."""
    for leg in ENGINE_LEGS:
        own = {Path(m).name for m, given in ONE_ENGINE_LEG.items() if given == leg}
        assert own & {"test_face_from_skull.py", "test_half_maximum.py", "test_face_skin.py"}, (leg, own)
        assert own & {"test_auto_landmarks.py", "test_scan_contents.py", "test_forensic.py"}, (leg, own)


def test_runs_on():
    main_only = next(m for m, leg in ONE_ENGINE_LEG.items() if leg == "main")
    other_only = next(m for m, leg in ONE_ENGINE_LEG.items() if leg == "5.3")
    unlisted = "tests/pde/test_pde_surface.py"
    assert unlisted not in ONE_ENGINE_LEG
    assert [runs_on(main_only, leg) for leg in ("main", "5.3", None)] == [True, False, True]
    assert [runs_on(other_only, leg) for leg in ("main", "5.3", None)] == [False, True, True]
    assert [runs_on(unlisted, leg) for leg in ("main", "5.3", None)] == [True, True, True]
    with pytest.raises(ValueError, match="PDEHEAD_ENGINE_LEG='4.2'"):
        runs_on(unlisted, "4.2")


def test_ci_run_names_the_same_engine_legs():
    text = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    named = re.search(r'^ENGINE_LEGS=" ([^"]*) "$', text, re.M)
    assert named and tuple(named.group(1).split()) == ENGINE_LEGS
    assert 'PDEHEAD_ENGINE_LEG="$engine_leg"' in text


def test_the_other_legs_modules_are_deselected_at_collection():
    main_only = next(m for m, leg in ONE_ENGINE_LEG.items() if leg == "main")
    other_only = next(m for m, leg in ONE_ENGINE_LEG.items() if leg == "5.3")

    def collected(leg: str | None) -> set[str]:
        env = {k: v for k, v in os.environ.items() if k != "PDEHEAD_ENGINE_LEG"}
        if leg:
            env["PDEHEAD_ENGINE_LEG"] = leg
        out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                              main_only, other_only], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
        return {line.split("::")[0] for line in out.stdout.splitlines() if "::" in line}

    assert collected(None) == {main_only, other_only}
    assert collected("main") == {main_only}
    assert collected("5.3") == {other_only}
