"""SIGINT / SIGTERM during training: finish the chunk in flight, log it, checkpoint, then stop.

A scheduler's SIGTERM and a first Ctrl-C only set a flag (nothing is cut off mid-write); the driver looks at it
between chunks. A second Ctrl-C stops at once (the last saved checkpoint stays valid), unless it comes while a
chunk's rows and checkpoint are written (:meth:`StopSignals.writing`): then it stops as soon as they are whole, so no
half-written checkpoint or metrics row is left behind. Before the first chunk
(compiling, allocating, restoring) a signal ends the process at once: nothing is lost there, and a compile cannot
be interrupted otherwise. The process exit status of ``ramavt train`` after such a stop is 128 + the signal number:
130 for SIGINT, 143 for SIGTERM.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

__all__ = ["StopSignals", "TrainingInterrupted"]


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on a signal after saving; ``exit_code`` is 128 + the signal number."""

    def __init__(self, message: str, signum: int = signal.SIGINT):
        super().__init__(message)
        self.signum = int(signum)
        self.exit_code = 128 + self.signum


class StopSignals:
    """Context manager: while active, SIGINT and SIGTERM set ``self.signum`` instead of raising (main thread only;
    elsewhere it does nothing). A second SIGINT raises KeyboardInterrupt. While ``hard_exit`` is set, a signal
    prints one line and exits the process with 128 + the signal number."""

    def __init__(self, log=print):
        self.signum: int | None = None
        # while set (what is in flight, e.g. 'while compiling'), a signal ends the process at once: a compile or a
        # large allocation can take minutes and cannot be interrupted, and nothing is lost before the first chunk
        self.hard_exit: str | None = None
        self._old: dict = {}
        self._log = log
        self._writing = 0  # inside writing(): a second Ctrl-C waits for the files to be whole
        self._stop_after_writing = False

    def _handle(self, signum, frame) -> None:
        if self.hard_exit is not None:  # compiling or allocating: nothing to save, and XLA cannot be interrupted
            print(
                f"\n{signal.Signals(signum).name} {self.hard_exit}: stopped; nothing was trained or written",
                file=sys.stderr,
                flush=True,
            )
            os._exit(128 + signum)
        if self.signum is not None and signum == signal.SIGINT:
            if self._writing:
                if not self._stop_after_writing:
                    self._log("\nCtrl-C: stopping once the checkpoint being written is whole")
                self._stop_after_writing = True
                return
            raise KeyboardInterrupt
        if self.signum is None:
            self._log(
                f"\n{signal.Signals(signum).name}: stopping at the next safe point (a chunk in flight is "
                f"finished, logged and checkpointed first); Ctrl-C again to stop now"
            )
        self.signum = signum

    @contextlib.contextmanager
    def writing(self, stop_after: bool = True):
        """A section that writes a chunk's rows and checkpoint: a second Ctrl-C in it is held until it ends, then
        raised as KeyboardInterrupt (``stop_after``; a section already on its way out drops it)."""
        self._writing += 1
        try:
            yield
        finally:
            self._writing -= 1
        if not self._writing and self._stop_after_writing:
            self._stop_after_writing = False
            if stop_after:
                raise KeyboardInterrupt

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old = {}
