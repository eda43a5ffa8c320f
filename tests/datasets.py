"""Where the real head CTs live and how each is loaded: one place for tests and scripts.

Real data is read in place from ``../shared/data`` (override with ``PDEHEAD_DATA``),
never copied. Locally a missing data set skips the test; in CI (CI=true) it fails,
because the real-data tests must run there.
"""
from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("PDEHEAD_DATA", ROOT.parent / "shared" / "data"))
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


# How each real data set is loaded; the single source of truth for tests and scripts.
CTHEAD_RAW16_OPTIONS = dict(format="raw", shape=(256, 256), dtype=">i2", spacing=(2.0, 1.0, 1.0),
                            first_slice="superior")
CTHEAD_TIFF8_OPTIONS = dict(spacing=(2.0, 1.0, 1.0), first_slice="superior")
