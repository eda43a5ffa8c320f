"""The tests' access to the real head CTs (the folder and the loader options are ``scripts/_common.py``'s).

Real data is read in place from ``../shared/data`` (override with ``PDEHEAD_DATA``),
never copied. Locally a missing data set skips the test; in CI (CI=true) it fails,
because the real-data tests must run there.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
# the data folder and how each data set is loaded: one owner, shared with the scripts (which never
# import from tests/)
from _common import CTHEAD_RAW16_OPTIONS, CTHEAD_TIFF8_OPTIONS, SHARED_DATA  # noqa: E402,F401

IN_CI = os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def shared_data(*parts: str) -> Path:
    """Path inside ../shared/data; skip the test if absent (fail instead in CI)."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        import pytest

        message = f"real data not found: {path}"
        if IN_CI:
            pytest.fail(message + " (CI must run the real-data tests)")
        pytest.skip(message)
    return path

