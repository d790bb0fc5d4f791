"""Process lifecycle: stop on SIGTERM/SIGINT, counted rejections, pacing on a clock."""

from __future__ import annotations

import logging
import signal
import threading
import time
from typing import Callable

log = logging.getLogger(__name__)


class StopFlag:
    """Set by SIGTERM or SIGINT (or by a test); programs poll or wait on it.

    The signal handler only records the signal. Setting the event there (it takes the event's lock)
    would deadlock when the signal lands while the main thread holds that lock, inside a wait; and
    logging there can re-enter a stream the main thread is writing. The first is_set or wait after
    the signal sets the event and logs it; wait looks every POLL_S [s].
    """

    POLL_S = 0.05

    def __init__(self, install_signals: bool = True) -> None:
        self.event = threading.Event()
        self.signalled: int | None = None
        if install_signals and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, self._on_signal)
            signal.signal(signal.SIGINT, self._on_signal)

    def _on_signal(self, signum, _frame) -> None:
        self.signalled = signum

    def set(self) -> None:
        self.event.set()

    def is_set(self) -> bool:
        if self.signalled is not None and not self.event.is_set():
            log.info("signal %s: stopping", signal.Signals(self.signalled).name)
            self.event.set()
        return self.event.is_set()

    def wait(self, timeout_s: float) -> bool:
        """True once set (or signalled), False after timeout_s [s]."""
        deadline = time.monotonic() + timeout_s
        while not self.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.event.wait(min(remaining, self.POLL_S))
        return True


class Rejections:
    """Counts and logs every rejected message; logging is rate-limited per reason."""

    def __init__(self, logger: logging.Logger, every: int = 100) -> None:
        self.count = 0
        self.by_key: dict[str, int] = {}
        self._log = logger
        self._every = every
        self._lock = threading.Lock()

    def reject(self, key: str, reason: str) -> None:
        with self._lock:
            self.count += 1
            kind = key.rsplit("/", 2)[-2] if key.count("/") >= 2 else key
            n = self.by_key[kind] = self.by_key.get(kind, 0) + 1
        if n <= 10 or n % self._every == 0:
            self._log.warning("rejected message #%d on %s: %s", n, key, reason)


def wall_clock() -> float:
    """Seconds since the UNIX epoch: the tracker's clock on a single host."""
    return time.time()


def pace(next_deadline_s: float, stop: StopFlag, clock: Callable[[], float] = wall_clock) -> None:
    """Wait until the clock reaches ``next_deadline_s`` or stop is set (pacing, not sync)."""
    remaining = next_deadline_s - clock()
    if remaining > 0:
        stop.wait(remaining)
