"""SIGINT / SIGTERM during training: finish the chunk in flight, log it, checkpoint, then stop.

A scheduler's SIGTERM and a first Ctrl-C only set a flag (nothing is cut off mid-write); the driver looks at it
between chunks. A second Ctrl-C stops at once (the last saved checkpoint stays valid). Before the first chunk
(compiling, allocating, restoring) a signal ends the process at once: nothing is lost there, and a compile cannot
be interrupted otherwise. The process exit status of ``ramavt train`` after such a stop is 128 + the signal number:
130 for SIGINT, 143 for SIGTERM.
"""

from __future__ import annotations

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

    def _handle(self, signum, frame) -> None:
        if self.hard_exit is not None:  # compiling or allocating: nothing to save, and XLA cannot be interrupted
            print(
                f"\n{signal.Signals(signum).name} {self.hard_exit}: stopped; nothing was trained or written",
                file=sys.stderr,
                flush=True,
            )
            os._exit(128 + signum)
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        if self.signum is None:
            self._log(
                f"\n{signal.Signals(signum).name}: stopping at the next safe point (a chunk in flight is "
                f"finished, logged and checkpointed first); Ctrl-C again to stop now"
            )
        self.signum = signum

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
