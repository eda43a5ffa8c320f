"""A stand-in for a Blender UI layout that records what a panel draws (headless Blender has no UI)."""
from __future__ import annotations

from types import SimpleNamespace


class RecordingLayout:
    """Records ``prop``, ``label``, ``operator`` ... calls of a panel's ``draw`` into ``log``."""

    def __init__(self, log):
        self.log, self.enabled = log, True

    def __getattr__(self, name):
        if name in ("row", "column", "box", "split"):
            return lambda *a, **k: RecordingLayout(self.log)
        if name == "operator":
            return lambda idname, **k: (self.log.append(("operator", idname)), SimpleNamespace())[1]
        return lambda *a, **k: self.log.append((name, a[1] if name == "prop" and len(a) > 1 else k.get("text")))
