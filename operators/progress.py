"""Progress of the long steps: the hook a runner sets (the modal pipeline, the CLI) and the engine
callback each step passes on (:func:`step_progress`)."""
from __future__ import annotations

#: ``hook(step, fraction, message)`` called by the long steps while a pipeline or an operator runs; it
#: may raise :class:`~pdehead_addon.Cancelled` (Esc in Blender, Ctrl-C on the CLI). Set by the runner.
PROGRESS_HOOK: list = [None]


def step_progress(step: str):
    """The engine progress callback for ``step`` (None when nobody listens)."""
    hook = PROGRESS_HOOK[0]
    if hook is None:
        return None
    return lambda fraction, message="": hook(step, fraction, message)
