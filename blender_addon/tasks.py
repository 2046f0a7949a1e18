"""Long operations that keep Blender responsive: progress in the status bar, Esc cancels, nothing left half-done.

A long operation is a generator of steps. Between two ``yield``s it does a bounded piece
of work; each ``yield`` hands back ``(share done, what it is doing)``; it ``return``s the
message to report. Whatever it has built so far it removes in a ``finally`` (or on
``GeneratorExit``), so closing it early (Esc) leaves the scene as it was, and its files are
written last, atomically. Run from a button, an operator steps it on a timer (``modal``)
and shows progress; run from a script, in background mode or in a test, ``execute`` runs it
to the end at once. Work that needs no ``bpy`` (generating textures, a city layout) runs
on a thread (`Threaded`), so the interface stays live during one long call.
"""

from __future__ import annotations

import threading
import time

import bpy

from ..meta_sim.core.errors import MetaSimError

TICK = 0.05  # seconds between timer events
SLICE = 0.1  # seconds of steps per timer event: the interface redraws in between
# Events a running operation lets through, so the view can still be moved (they change no data).
NAVIGATION = {"MOUSEMOVE", "INBETWEEN_MOUSEMOVE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "MIDDLEMOUSE", "TRACKPADPAN",
              "TRACKPADZOOM", "MOUSEROTATE", "MOUSESMARTZOOM", "NDOF_MOTION"}

_running: dict[str, str] = {}  # operator idname -> what it is doing, while a long operation runs


def busy() -> str | None:
    """What a running long operation is doing, or None: other operators wait for it (their poll says so)."""
    return next(iter(_running.values()), None)


def poll_idle(cls) -> bool:
    """For ``poll``: False, with the reason, while a long operation runs."""
    doing = busy()
    if doing is not None:
        cls.poll_message_set(f"Wait until Meta-Sim has finished ({doing}) or press Esc to cancel it")
        return False
    return True


def run(steps):
    """Run a generator of steps to the end; its return value."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def scaled(steps, text: str, start: float = 0.0, end: float = 1.0):
    """Steps of a generator that yields only its share done (such as ``CityScene.render_rgb_in_strips``),
    as ``(share, text)`` between ``start`` and ``end``; its return value."""
    try:
        while True:
            try:
                share = next(steps)
            except StopIteration as done:
                return done.value
            yield start + (end - start) * share, text
    finally:
        steps.close()


class Cancelled(Exception):
    """Raised inside work on a thread at its next progress call once it is cancelled."""


class Threaded:
    """Pure work on a thread: ``work(progress)`` where ``progress(n)`` reports ``n`` more of ``total`` units
    done (and raises `Cancelled` once the operation is cancelled)."""

    def __init__(self, work, total: int = 0):
        self.total, self.done = total, 0
        self._work, self._result, self._error = work, None, None
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._main, name="meta-sim", daemon=True)

    def _progress(self, n: int = 1) -> None:
        if self._cancel.is_set():
            raise Cancelled
        self.done += n

    def _main(self) -> None:
        try:
            self._result = self._work(self._progress)
        except BaseException as exc:  # handed to the main thread
            self._error = exc

    def wait(self, text: str, start: float = 0.0, end: float = 1.0):
        """Steps: start the work and yield progress (between ``start`` and ``end``) until it ends; its result.
        Closed early, it asks the work to stop and waits a moment for it (the work writes nothing in place
        until it is complete, so one that is still running is left to finish and dropped)."""
        self._thread.start()
        try:
            while self._thread.is_alive():
                self._thread.join(TICK / 2)
                share = self.done / self.total if self.total else 0.0
                yield start + (end - start) * min(share, 1.0), text
        finally:
            self._cancel.set()
            self._thread.join(1.0)
        if self._error is not None:
            raise self._error
        return self._result


def interactive(context) -> bool:
    """Whether an event loop will send timer events (not so in background mode: ``blender -b``, the bpy module)."""
    return context.window is not None and not bpy.app.background


class Reporting:
    """Operator mixin: ``execute`` runs ``run(context, settings)`` and turns the errors a user can cause
    (MetaSimError, file-system errors) into an error report instead of a traceback."""

    def execute(self, context):
        return self.guarded(lambda: self.run(context, context.scene.meta_sim))

    def guarded(self, action):
        try:
            return action()
        except MetaSimError as exc:
            self.report({"ERROR"}, str(exc))
        except OSError as exc:
            self.report({"ERROR"}, f"{exc.filename or 'file'}: {exc.strerror}")
        return {"CANCELLED"}


class Stepped(Reporting):
    """Operator mixin for a long operation: ``steps(context, settings)`` is its generator of steps."""

    def execute(self, context):
        return self.guarded(lambda: self._finished(run(self.steps(context, context.scene.meta_sim))))

    def invoke(self, context, event):
        if not interactive(context):
            return self.execute(context)
        self._steps = self.steps(context, context.scene.meta_sim)
        wm = context.window_manager
        self._timer = wm.event_timer_add(TICK, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        _running[self.bl_idname] = self.bl_label.lower()
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._end(context)
            self.report({"WARNING"}, f"{self.bl_label} cancelled: nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"PASS_THROUGH"} if event.type in NAVIGATION else {"RUNNING_MODAL"}
        return self.guarded(lambda: self._advance(context))

    def cancel(self, context):
        """Blender ends the operation itself (a file is loaded, the window closes): as Esc, quietly."""
        self._end(context)

    def _advance(self, context):
        """Steps for up to ``SLICE`` seconds, then the progress display."""
        deadline, share, text = time.monotonic() + SLICE, 0.0, ""
        try:
            while time.monotonic() < deadline:
                share, text = next(self._steps)
                _running[self.bl_idname] = text
        except StopIteration as done:
            self._end(context)
            return self._finished(done.value)
        except BaseException:
            self._end(context)
            raise
        context.window_manager.progress_update(int(1000 * min(max(share, 0.0), 1.0)))
        context.workspace.status_text_set(f"Meta-Sim: {text} ({share:.0%}); Esc to cancel")
        return {"RUNNING_MODAL"}

    def _end(self, context) -> None:
        """Close the steps (an unfinished operation removes what it built) and the progress display."""
        self._steps.close()
        _running.pop(self.bl_idname, None)
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)

    def _finished(self, message):
        """Report what the steps returned: a message, or (report type, message)."""
        kind, message = message if isinstance(message, tuple) else ({"INFO"}, message)
        if message:
            self.report(kind, message)
        return {"FINISHED"}
