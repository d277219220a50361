"""Worker threads of the studio window. No Open3D GUI import: results go back through a
``post(fn)`` callable: the studio's inbox, emptied on the main thread between Open3D ticks
(tests pass a plain function).

- :class:`Worker`: one thread running jobs in order. Jobs submitted under the same ``key`` while
  one is still waiting replace it (a slider dragged across ten values runs the last one only).
- :class:`CancelToken`: set by the Cancel button; long jobs call ``check()`` in their progress
  callbacks and stop with :class:`app.gui.model.Cancelled`.
"""

from __future__ import annotations

import threading
import traceback
from collections import OrderedDict
from collections.abc import Callable

from app.gui.model import Cancelled

Post = Callable[[Callable[[], None]], None]


class CancelToken:
    def __init__(self):
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        if self._event.is_set():
            raise Cancelled("cancelled")


class Worker:
    """A background thread that runs ``fn()`` jobs and posts ``on_done(result)`` or
    ``on_error(exc)`` to the main thread."""

    def __init__(self, post: Post, name: str = "worker"):
        self.post = post
        self._jobs: OrderedDict[object, tuple] = OrderedDict()
        self._cond = threading.Condition()
        self._busy = False
        self._stop = False
        self._counter = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(
        self,
        fn: Callable[[], object],
        on_done: Callable[[object], None] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        key: object = None,
    ) -> None:
        """Queue ``fn``; a waiting job with the same non-None ``key`` is replaced."""
        with self._cond:
            if key is None:
                self._counter += 1
                key = ("_anon", self._counter)
            self._jobs.pop(key, None)
            self._jobs[key] = (fn, on_done, on_error)
            self._cond.notify()

    @property
    def idle(self) -> bool:
        with self._cond:
            return not self._busy and not self._jobs

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._jobs.clear()
            self._cond.notify()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._jobs and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                _, (fn, on_done, on_error) = self._jobs.popitem(last=False)
                self._busy = True
            try:
                result = fn()
            except BaseException as exc:  # noqa: BLE001 - every failure goes to a dialog
                if not isinstance(exc, Cancelled):
                    traceback.print_exc()
                if on_error is not None:
                    self.post(lambda e=exc, f=on_error: f(e))
            else:
                if on_done is not None:
                    self.post(lambda r=result, f=on_done: f(r))
            finally:
                with self._cond:
                    self._busy = False
