"""Progress of long Stan work: sampling (iterations across chains) and
compiles (a ticking line per program). On a terminal, tqdm bars on stderr;
elsewhere (a log file, CI), a compact log: a line per quarter of a fit's
iterations, a line a minute per compile. A fit run for a fit runner (many
fits at once) shows none: the runner shows the fits done.

PyStan reports sampling progress by writing lines such as
``Sampling:  42% (840/2000)`` to ``sys.stderr`` (clikit, PyStan's console
output) as it polls httpstan; ProgressStream reads them and drives the bar,
and passes on everything else PyStan writes (held back unless sampling fails)."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import re
import sys
import threading
import time
from collections.abc import Iterator
from typing import TextIO

logger = logging.getLogger("stancal")

LOG_QUARTERS = 4  # a non-terminal log says a fit's progress at each quarter
COMPILE_LOG_EVERY_S = 60.0  # a non-terminal log says each running compile's time this often

_quiet = False  # set while a fit runner's task runs


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """No progress within the block (a fit among many: the fit runner shows the fits done)."""
    global _quiet
    before, _quiet = _quiet, True
    try:
        yield
    finally:
        _quiet = before


def terminal_stream() -> TextIO | None:
    """Where bars are drawn: a copy of stderr when it is a terminal (it stays
    the terminal while the backend holds back what fds 1 and 2 receive), else None."""
    if not sys.stderr.isatty():
        return None
    return os.fdopen(os.dup(sys.stderr.fileno()), "w")


def _width(stream: TextIO) -> int:
    """The terminal's width; a terminal that reports none (a bare pseudo-terminal) gets 100 columns."""
    try:
        return os.get_terminal_size(stream.fileno()).columns or 100
    except (OSError, ValueError, io.UnsupportedOperation):
        return 100


class SamplingProgress:
    """A fit's iterations across chains: a bar on ``stream``, or log lines at its quarters."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None) -> None:
        from tqdm import tqdm

        self.label, self.total, self.done = label, total, 0
        self.started = time.perf_counter()
        self._logged = 0
        self.bar = None if stream is None else tqdm(total=total, desc=label, unit="it", file=stream,
                                                    ncols=_width(stream), leave=True)

    def update(self, done: int) -> None:
        """``done`` iterations of all chains so far."""
        done = min(done, self.total)
        if self.bar is not None:
            self.bar.update(done - self.bar.n)
        quarter = LOG_QUARTERS * done // self.total
        if self.bar is None and quarter > self._logged and done < self.total:
            self._logged = quarter
            logger.info("%s: %d %% (%d/%d iterations, %.0f s)", self.label, 100 * done // self.total, done,
                        self.total, time.perf_counter() - self.started)
        self.done = done

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


# PyStan's progress line (stan/model.py): "Sampling: 42% (840/2000)", then "..., done."; a fit
# httpstan had cached gives "Sampling: 100%, done." without counts
_PROGRESS = re.compile(r"Sampling:\s+\d+%(?:\s+\((\d+)/(\d+)\))?(,\s*done\.)?")


class ProgressStream(io.TextIOBase):
    """A stand-in for sys.stderr while PyStan samples: its progress lines
    drive ``progress``; every other line goes on to ``forward``."""

    def __init__(self, progress: SamplingProgress, forward: TextIO) -> None:
        self.progress, self.forward = progress, forward
        self._partial = ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        lines = (self._partial + text).split("\n")
        self._partial = lines.pop()
        for line in lines:
            self._line(line)
        return len(text)

    def flush(self) -> None:
        if self._partial and _PROGRESS.search(self._partial):  # a finished progress line
            self._line(self._partial)
            self._partial = ""
        self.forward.flush()

    def _line(self, line: str) -> None:
        found = _PROGRESS.search(line)
        if found is None:
            if line.strip():
                self.forward.write(line + "\n")
            return
        if found.group(1):
            self.progress.update(int(found.group(1)))
        if found.group(3):  # done: also when httpstan served the fit from its cache, without counts
            self.progress.update(self.progress.total)


@contextlib.contextmanager
def sampling_progress(label: str, total: int) -> Iterator[SamplingProgress | None]:
    """A fit's progress (None when quiet()): its bar drawn on the terminal
    as it is on entering the block, whatever the block does with fds 1 and 2."""
    if _quiet:
        yield None
        return
    stream = terminal_stream()
    progress = SamplingProgress(label, total, stream)
    try:
        yield progress
    finally:
        progress.close()
        if stream is not None:
            stream.close()


@contextlib.contextmanager
def progress_lines(progress: SamplingProgress | None) -> Iterator[None]:
    """PyStan's progress lines, written to sys.stderr within the block, drive
    ``progress``; what else it writes goes on to the sys.stderr of entry."""
    if progress is None:
        yield
        return
    with contextlib.redirect_stderr(ProgressStream(progress, sys.stderr)) as reader:
        yield
        reader.flush()


class Ticker:
    """The tasks of one ``ticking`` block: each is queued until ``start``,
    and counts its own time from then until ``done`` (a program queued
    behind others for a core has not been compiling all that while)."""

    def __init__(self, names: list[str], what: str, stream: TextIO | None) -> None:
        self.what, self.stream = what, stream
        self.started: dict[str, float] = {}  # running tasks: name -> start
        self.lock = threading.Lock()  # the ticks, start() and done() come from different threads
        self.bars = {}
        if stream is not None:
            from tqdm import tqdm

            self.bars = {name: tqdm(desc=f"{what} {name}", bar_format="{desc}: queued", file=stream,
                                    ncols=_width(stream), leave=True) for name in names}

    def start(self, name: str) -> None:
        with self.lock:
            self.started[name] = time.perf_counter()
            if name in self.bars:
                self.bars[name].bar_format = "{desc}: {elapsed}{postfix}"
                self.bars[name].reset()  # its clock starts now

    def tick(self) -> None:
        with self.lock:
            for name, since in sorted(self.started.items()):
                if name in self.bars:
                    self.bars[name].refresh()
                elif self.stream is None and not _quiet:
                    logger.info("%s %s: %.0f s so far", self.what, name, time.perf_counter() - since)

    def done(self, name: str) -> None:
        self._end(name, "done", "done in")

    def failed(self, name: str) -> None:
        self._end(name, "failed", "failed after")

    def _end(self, name: str, shown: str, logged: str) -> None:
        with self.lock:
            seconds = time.perf_counter() - self.started.pop(name)
            if name in self.bars:  # its line is frozen, and closed with the others at the end: bars closed
                bar = self.bars[name]  # one by one as they finish, out of order, leave stray lines behind
                bar.bar_format = f"{{desc}}: {bar.format_interval(seconds)}, {shown}"
                bar.refresh()
            elif not _quiet:
                logger.info("%s %s: %s %.0f s", self.what, name, logged, seconds)


@contextlib.contextmanager
def ticking(names: list[str], what: str = "compiling") -> Iterator[Ticker]:
    """A line per long task that counts its time from its ``start(name)``
    until the block calls ``done(name)``: a bar per task on a terminal,
    ticking every second; elsewhere a log line per running task a minute,
    and one when it ends."""
    stream = None if _quiet else terminal_stream()
    ticker = Ticker(names, what, stream)
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(1.0 if stream is not None else COMPILE_LOG_EVERY_S):
            ticker.tick()

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield ticker
    finally:
        stop.set()
        thread.join()
        for bar in ticker.bars.values():
            bar.close()
        if stream is not None:
            stream.close()
