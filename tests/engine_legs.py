"""Which of the two engine legs of ``.ci/run`` runs each real-head engine module.

Two legs of ``.ci/run`` run the engine's tests: main (bpy 5.0.1: Python 3.11, numpy 1.26) and 5.3 (Python 3.13,
numpy 2.5). Run alone, either runs every engine module. When ``.ci/run`` runs both, it names the leg in
``PDEHEAD_ENGINE_LEG``, and each module below runs on the leg named here only: its minutes go to segmenting real
heads, searching their landmarks and building faces from their skulls, the same steps twice over. So:

- every test still runs once in every CI run;
- both legs still run every module not listed here, on their own Python and numpy: every engine step on the
  phantom and on small made inputs, and CThead's and GE's segmentation, boundaries and surfaces;
- and the matrix fits CI's 90 minutes. When both legs ran every module it took 5,415 s on this machine
  and timed out in CI (main leg 4,507 s + 4.5 leg after it).

Each half holds real-head face and landmark tests, so that both numpy versions build a face from CThead's
skull. The halves are balanced by the main leg's ``--durations`` (see docs/development.md).
"""
from __future__ import annotations

ENGINE_LEGS = ("main", "5.3")

# Module path (from the repo root) -> the engine leg that runs it when .ci/run runs both.
# Seconds: each module's time on the main leg's Python alone (session 33, --durations, nothing else running); about
# 1.3 times that beside another leg in .ci/run. The shared session fixtures (tests/conftest.py: CThead's skull and
# landmark search, GE's segmentation) are made on both legs. Each leg's half comes to ~880 s; session 33's full
# .ci/run then took main 3,451 s + 4.5 1,039 s and 5.3 3,498 s + 4.2 1,006 s: 4,546 s in all.
ONE_ENGINE_LEG = {
    "tests/forensic/test_auto_landmarks.py": "main",  # 498 s
    "tests/forensic/test_skull_only.py": "main",  # 209 s
    "tests/forensic/test_half_maximum.py": "main",  # 85 s
    "tests/forensic/test_scan_contents.py": "5.3",  # 370 s
    "tests/forensic/test_face_from_skull.py": "5.3",  # 203 s
    "tests/forensic/test_metal_streaks.py": "5.3",  # 156 s
    "tests/forensic/test_depth_plausibility.py": "5.3",  # 153 s
    "tests/forensic/test_forensic.py": "5.3",  # 90 s
}


def checked_leg(leg: str | None) -> str | None:
    """``leg`` (PDEHEAD_ENGINE_LEG's value) if it names an engine leg, None if empty; ValueError otherwise."""
    if not leg:
        return None
    if leg not in ENGINE_LEGS:
        raise ValueError(f"PDEHEAD_ENGINE_LEG={leg!r}: expected one of {', '.join(ENGINE_LEGS)}")
    return leg


def runs_on(module: str, leg: str | None) -> bool:
    """Whether the test module at ``module`` (a path from the repo root) runs on engine leg ``leg``.

    ``leg`` None (a plain pytest run, or ``.ci/run`` with one engine leg) runs everything.
    """
    leg = checked_leg(leg)
    return leg is None or ONE_ENGINE_LEG.get(module, leg) == leg
