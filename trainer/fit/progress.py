"""What a fit shows while it runs, and the lock that keeps one fit at a time in a run folder.

On a terminal, one bar for the whole command redraws in place. Elsewhere (a log file, nohup, systemd,
CI) a redraw would be one more line each time, so the bar prints a line when each phase begins and
one at least every ``LOG_EVERY_S`` seconds from a thread of its own, whatever the phase is doing.
"""

from __future__ import annotations

import fcntl
import os
import sys
import threading
import time
from pathlib import Path
from types import TracebackType

from tqdm import tqdm

from contract.errors import UserError

#: Off a terminal, a progress line at least this often.
LOG_EVERY_S = 30.0
#: The file in a run folder that a running fit holds locked (with its process id inside).
LOCK_FILE = "fit.lock"


class Progress:
    """One bar for the whole command: its phase, the seconds of budget used, and the ETA."""

    FORMAT = "{desc}{percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}]"  # desc ends ": "

    def __init__(self, budget_s: float, started: float, live: bool | None = None, every_s: float = LOG_EVERY_S):
        self.started = started
        self.live = sys.stderr.isatty() if live is None else live
        self.bar = tqdm(
            total=round(budget_s), desc="reading", bar_format=self.FORMAT, dynamic_ncols=True, disable=not self.live
        )
        self.description, self.total, self.n = "reading", round(budget_s), 0
        self.closed = threading.Event()
        self.logger: threading.Thread | None = None
        if not self.live:
            self.logger = threading.Thread(target=self._log_every, args=(every_s,), daemon=True)
            self.logger.start()

    def phase(self, name: str) -> None:
        self.description = name
        self.bar.set_description(name)
        self.tick()
        if not self.live:
            self._log()

    def tick(self, *_: int) -> None:
        self.n = min(self.total, round(time.monotonic() - self.started))
        self.bar.n = self.n
        self.bar.refresh()

    def say(self, line: str) -> None:
        self.bar.write(line)

    def finish(self) -> None:
        """The command is done: the bar ends full, at the seconds it took (within the budget, or past it)."""
        self.tick()
        self.total = self.bar.total = max(1, self.n)
        self.description = "done"
        self.bar.set_description("done")

    def close(self) -> None:
        """Stop the bar where the command ended (full when it finished), before anything else is printed."""
        self.closed.set()
        if self.logger is not None:
            self.logger.join()
        self.tick()
        self.bar.close()
        if not self.live:
            self._log()

    def _log(self) -> None:
        """The bar as one line of the log."""
        elapsed = time.monotonic() - self.started
        n = min(self.total, round(elapsed))
        prefix = f"{self.description}: "
        line = tqdm.format_meter(n, self.total, elapsed, ncols=80, prefix=prefix, bar_format=self.FORMAT)
        print(line, file=sys.stderr, flush=True)

    def _log_every(self, every_s: float) -> None:
        while not self.closed.wait(every_s):
            self._log()


class RunLock:
    """Holds ``fit.lock`` in a run folder while a fit writes there; a second fit into it stops at once.

    An advisory ``flock``: the kernel lets it go when the process ends, however it ends, so a crashed
    fit never leaves a stale lock behind.
    """

    def __init__(self, run: Path):
        self.path = Path(run) / LOCK_FILE
        self.handle = None

    def __enter__(self) -> RunLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(self.path, "a+")  # held open, and locked, for the whole fit
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            raise UserError(
                f"{self.path.parent}: a fit is already writing here ({holder}); wait for it to end, or pass --out "
                "elsewhere"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"pid {os.getpid()}, started {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        handle.flush()
        self.handle = handle
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        fcntl.flock(self.handle, fcntl.LOCK_UN)
        self.handle.close()
