"""Exceptions raised by the PDE Head engine.

Every error a user can cause (bad files, bad parameters) is a :class:`PDEHeadError`
whose message names the file (when there is one) and the problem, so that the
Blender layer can show it as a report instead of a traceback.
"""
from __future__ import annotations

import os


class PDEHeadError(Exception):
    """Base class of all errors the engine raises on purpose."""


class CTImportError(PDEHeadError, ValueError):
    """A CT input (folder, file, series) cannot be read as asked.

    Parameters
    ----------
    message : str
        What is wrong, in words a user understands.
    path : str or os.PathLike, optional
        The file or folder concerned; it is prefixed to the message.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        self.problem = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class SegmentationError(PDEHeadError, ValueError):
    """The head cannot be segmented from the volume (e.g. nothing above air)."""


class BoundaryError(PDEHeadError, ValueError):
    """Boundary curves cannot be extracted or are inconsistent."""


class PDEError(PDEHeadError, ValueError):
    """The PDE surface cannot be solved or evaluated with the given input."""


class StorageError(PDEHeadError, ValueError):
    """A boundary file is unreadable, truncated or of an unknown version."""


class Cancelled(Exception):
    """Raised by a progress callback to stop a long engine step (Esc in Blender, Ctrl-C on the CLI).

    Not a :class:`PDEHeadError`: nothing is wrong. A step that is cancelled returns nothing and
    leaves nothing behind (worker threads are stopped, inputs are not modified).
    """

    def __init__(self, message: str = "cancelled"):
        super().__init__(message)


def report_progress(progress, fraction: float, message: str = "") -> None:
    """Call ``progress(fraction, message)`` when a callback is given (it may raise :class:`Cancelled`).

    ``fraction`` is clipped to [0, 1]; the engine's long steps (``segment_head``,
    ``extract_boundaries``, ``w_field``, ``SolidCTTable``) report at least every few hundred
    milliseconds on a head scan.
    """
    if progress is not None:
        progress(min(max(float(fraction), 0.0), 1.0), message)


def scaled_progress(progress, start: float, stop: float):
    """A callback mapping [0, 1] onto [start, stop] of ``progress`` (None stays None)."""
    if progress is None:
        return None
    return lambda fraction, message="": progress(start + (stop - start) * fraction, message)
