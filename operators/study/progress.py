"""Progress of the long steps: the hook a runner sets (the modal pipeline, the CLI) and the engine
callback each step passes on (:func:`step_progress`)."""
from __future__ import annotations

import threading
import time

from ...pdehead_addon import Cancelled
from .. import state


def set_hook(hook) -> None:
    """Install ``hook(step, fraction, message)``, called by the long steps while a pipeline or an operator
    runs (it may raise :class:`~pdehead_addon.Cancelled`: Esc in Blender, Ctrl-C on the CLI); None removes it.
    Kept in ``state.REGISTRY.progress_hook``."""
    state.REGISTRY.progress_hook = hook


def step_progress(step: str):
    """The engine progress callback for ``step`` (None when nobody listens)."""
    hook = state.REGISTRY.progress_hook
    if hook is None:
        return None
    return lambda fraction, message="": hook(step, fraction, message)


class EngineJob:
    """An engine call that touches no Blender data, run on a worker thread so that the modal pipeline
    keeps reading events while it works: Esc sets :attr:`cancel_requested`, which the call's progress
    callback turns into :class:`~pdehead_addon.Cancelled` at its next report (a Chan-Vese iteration, a
    batch of the curves' search: well under a second on a clinical scan), instead of waiting for the
    step to end.

    Parameters
    ----------
    call : callable
        ``call(progress) -> result``; ``progress(fraction, message="")`` as the engine's long steps take it.

    The worker only records the fraction; the main thread reads it (:attr:`fraction`) for Blender's
    progress indicator, since Blender's data and window manager must not be touched from a thread.
    """

    def __init__(self, call):
        self.fraction = 0.0
        self.message = ""
        self.cancel_requested = False
        self.result = None
        self.error: BaseException | None = None
        self.seconds = 0.0
        self._clock = time.perf_counter

        def work():
            start = self._clock()
            try:
                self.result = call(self.progress)
            except BaseException as exc:  # noqa: BLE001 - handed to the main thread by finish()
                self.error = exc
            self.seconds = self._clock() - start
        self._thread = threading.Thread(target=work, name="pdehead-engine-step", daemon=True)
        self._thread.start()

    def progress(self, fraction: float, message: str = "") -> None:
        if self.cancel_requested:
            raise Cancelled("cancelled (Esc)")
        self.fraction, self.message = float(fraction), message

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def cancel(self, timeout: float | None = None) -> None:
        """Ask the call to stop and wait until it has (its next progress report)."""
        self.cancel_requested = True
        self._thread.join(timeout)

    def finish(self):
        """The call's result once :attr:`done`; its exception re-raised here, on the main thread."""
        self._thread.join()
        if self.error is not None:
            raise self.error
        return self.result
