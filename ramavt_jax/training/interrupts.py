"""SIGINT / SIGTERM during training: finish the chunk in flight, log it, checkpoint, then stop.

A scheduler's SIGTERM and a first Ctrl-C only set a flag (nothing is cut off mid-compile or mid-write); the driver
looks at it between chunks. A second Ctrl-C stops at once (the last saved checkpoint stays valid). The process
exit status of ``ramavt train`` after such a stop is 128 + the signal number: 130 for SIGINT, 143 for SIGTERM.
"""

from __future__ import annotations

import signal
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
    elsewhere it does nothing). A second SIGINT raises KeyboardInterrupt."""

    def __init__(self, log=print):
        self.signum: int | None = None
        self._old: dict = {}
        self._log = log

    def _handle(self, signum, frame) -> None:
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        if self.signum is None:
            self._log(f"\n{signal.Signals(signum).name}: stopping at the next safe point (a chunk in flight is "
                      f"finished, logged and checkpointed first); Ctrl-C again to stop now")
        self.signum = signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old = {}
