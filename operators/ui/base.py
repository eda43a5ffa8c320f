"""The one ``execute`` of every PDE Head operator: fetch the study (or cancel), run, report.

An operator subclasses :class:`GuardedOperator` (works without a study: import, phantom, pipeline) or
:class:`StudyOperator` (works on the active study or the one named by its ``study`` property) and
writes ``run``; ``execute`` is the template here. Every failure is caught by :func:`guarded`: the
engine's :class:`PDEHeadError` (and, as a last resort, any other exception) is reported as an ERROR
and the operator returns ``{'CANCELLED'}`` after removing whatever it had created
(:class:`operators.study.pipeline_run.Rollback`), so a failed step never leaves half-built objects behind.
"""
from __future__ import annotations

import traceback

from bpy.props import StringProperty

from ...pdehead_addon import Cancelled, PDEHeadError
from .. import state
from ..state import NO_STUDY_MESSAGE, suspended_updates
from ..study.entity import Study
from ..study.pipeline_run import Rollback


def report_exception(op, exc: BaseException) -> None:
    """Report ``exc`` on ``op`` in the user's words (a bug: the traceback goes to the console)."""
    if isinstance(exc, Cancelled):
        op.report({'WARNING'}, "PDE Head: cancelled; the study is as it was before")
    elif isinstance(exc, PDEHeadError):
        op.report({'ERROR'}, state.user_text(str(exc)))
    else:  # a bug: keep the details in the console, give the user one clear line
        traceback.print_exc()
        op.report({'ERROR'}, f"PDE Head internal error: {type(exc).__name__}: {exc}")


def set_status(context, text: str | None) -> None:
    """The workspace's status bar text (None clears it); nothing without a UI."""
    workspace = getattr(context, "workspace", None)
    if workspace is not None:
        try:
            workspace.status_text_set(text)
        except (AttributeError, RuntimeError):
            pass


def guarded(op, context, body) -> set:
    """Run ``body()``; on any error report it, undo what it created and cancel.

    With a UI, the wait cursor/progress indicator and the status bar show the step meanwhile.
    """
    rollback = Rollback()
    wm = context.window_manager if getattr(context, "window", None) is not None else None
    if wm is not None:
        wm.progress_begin(0, 1)
        set_status(context, f"PDE Head: {op.bl_label}...")
    try:
        result = body()
    except Exception as exc:  # noqa: BLE001 - every failure must reach the user as a report
        rollback.undo()
        report_exception(op, exc)
        return {'CANCELLED'}
    finally:
        if wm is not None:
            wm.progress_end()
            set_status(context, None)
    return result if result is not None else {'FINISHED'}


class GuardedOperator:
    """Mixin: ``execute`` runs :meth:`run` under :func:`guarded`."""

    def run(self, context):
        """The operator's work; reports what it did. Returns None ({'FINISHED'}) or an operator result."""
        raise NotImplementedError(type(self).__name__)

    def execute(self, context):
        return guarded(self, context, lambda: self.run(context))


class StudyOperator(GuardedOperator):
    """Mixin: operators that work on the active study (or the one named by ``study``).

    ``execute`` fetches the :class:`~operators.study.entity.Study`
    (no study: an ERROR report and ``{'CANCELLED'}``), then runs
    ``run(context, study)`` under :func:`guarded`, ``study`` being that :class:`~operators.study.entity.Study`.
    """

    study: StringProperty(name="Study", default="", options={'SKIP_SAVE'},
                          description="Collection name of the study (empty: the active study)")

    #: Operator properties that mirror the study's settings: read when invoked, written back when run.
    mirrored_settings = ()

    @classmethod
    def poll(cls, context):
        if state.active_study(context) is not None or state.studies():
            return True
        cls.poll_message_set(NO_STUDY_MESSAGE)
        return False

    def invoke(self, context, event):
        study = Study.active(context, self.study)
        if study is not None:
            s = study.settings
            for name in self.mirrored_settings:
                setattr(self, name, getattr(s, name))
        return self.execute(context)

    def execute(self, context):
        study = Study.active(context, self.study)
        if study is None:
            self.report({'ERROR'}, NO_STUDY_MESSAGE)
            return {'CANCELLED'}
        return guarded(self, context, lambda: self.run(context, study))

    def run(self, context, study: Study):
        raise NotImplementedError(type(self).__name__)

    def store_settings(self, s) -> None:
        """Copy the operator's values into the study settings without triggering live rebuilds.

        A value the caller did not set (``bpy.ops.pdehead.build_solid()`` from a script or
        headless, where invoke is not called) is taken from the study instead, so running an
        operator never resets the study's settings to the operator's defaults.
        """
        is_set = getattr(getattr(self, "properties", None), "is_property_set", None)
        with suspended_updates():
            for name in self.mirrored_settings:
                if is_set is not None and not is_set(name):
                    setattr(self, name, getattr(s, name))
                else:
                    setattr(s, name, getattr(self, name))
