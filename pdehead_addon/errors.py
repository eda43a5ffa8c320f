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
