"""Progress of long work through the :mod:`logging` module.

The package logs to the ``msam_torch`` logger; a progress record carries ``task``, ``done`` and
``total`` (:func:`step`, :func:`tracked`). The command line shows them with :class:`ProgressHandler`:
on a terminal a tqdm bar per task with its total and ETA; otherwise a line when the stage changes
or ends, at most one every ``every`` seconds within a stage, and a line every ``every`` seconds
while a stage runs without reporting (so a log file shows the work going on before it finishes).
"""
from __future__ import annotations

import logging
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator, TextIO

LOGGER = logging.getLogger("msam_torch")


def step(logger: logging.Logger, task: str, message: str, done: int, total: int) -> None:
    """Log that ``task`` has done ``done`` of ``total`` steps and now does ``message``."""
    logger.info("%s", message, extra={"task": task, "done": done, "total": total})


def tracked(items: Iterable, logger: logging.Logger, task: str, name: Callable[[object], str],
            total: int | None = None, first: int = 0) -> Iterator:
    """Yield ``items``, logging a progress record before each: step ``first + k`` of ``total``
    (default: their count)."""
    items = list(items)
    for done, item in enumerate(items, first):
        step(logger, task, name(item), done, len(items) if total is None else total)
        yield item


class ProgressHandler(logging.Handler):
    """Writes the package's log records to ``stream``; progress records as a bar (``terminal``)
    or as throttled lines with elapsed time and ETA, plus a heartbeat line every ``every`` seconds."""

    def __init__(self, stream: TextIO, terminal: bool, every: float = 5.0):
        super().__init__()
        self.stream, self.terminal, self.every = stream, terminal, every
        self.bar, self.task, self.message = None, None, ""
        self.started = self.last = time.monotonic()
        self.done, self.total = 0, 0
        self._stop = threading.Event()
        self._heartbeat = None
        if not terminal:
            self._heartbeat = threading.Thread(target=self._beat, name="msam-progress", daemon=True)
            self._heartbeat.start()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            if getattr(record, "task", None) is None:  # a plain message: the stage it follows has ended
                with self.lock:
                    self.task = None
                    self._write(f"{record.levelname.lower()}: {record.getMessage()}")
                return
            with self.lock:
                self._progress(record.task, record.getMessage(), record.done, record.total)
        except Exception:  # a failing handler must not end the run
            self.handleError(record)

    def _progress(self, task: str, message: str, done: int, total: int) -> None:
        now = time.monotonic()
        if task != self.task:
            self._close_bar()
            self.task, self.started, self.last = task, now, 0.0
        changed = message != self.message
        self.message, self.done, self.total = message, done, total
        if self.terminal:
            if self.bar is None:
                from tqdm.auto import tqdm

                self.bar = tqdm(total=total, desc=task, unit="step", file=self.stream, leave=False)
            self.bar.total = total
            self.bar.set_postfix_str(message, refresh=False)
            self.bar.update(done - self.bar.n)
        elif changed or done == total or now - self.last >= self.every:
            self._line(now)

    def _line(self, now: float) -> None:
        elapsed = now - self.started
        eta = f", about {elapsed / self.done * (self.total - self.done):.0f} s left" if 0 < self.done < self.total else ""
        self._write(f"{self.task}: {self.done}/{self.total} {self.message} ({elapsed:.0f} s{eta})")
        self.last = now

    def _beat(self) -> None:
        while not self._stop.wait(self.every / 5):
            with self.lock:
                if self.task is not None and time.monotonic() - self.last >= self.every:
                    self._line(time.monotonic())

    def _write(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text, file=self.stream)
        else:
            self.stream.write(text + "\n")
            self.stream.flush()

    def _close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def close(self) -> None:
        self._stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join()
        with self.lock:
            self._close_bar()
            self.task = None
        super().close()


@contextmanager
def logging_to(stream: TextIO, verbosity: int = 0, every: float = 5.0) -> Iterator[ProgressHandler]:
    """The package's log records to ``stream`` for the block: warnings only (``verbosity`` < 0,
    ``-q``), progress (0) or everything (> 0, ``-v``)."""
    handler = ProgressHandler(stream, terminal=stream.isatty(), every=every)
    level = logging.WARNING if verbosity < 0 else logging.INFO if verbosity == 0 else logging.DEBUG
    previous = LOGGER.level, LOGGER.propagate
    LOGGER.addHandler(handler)
    LOGGER.setLevel(level)
    LOGGER.propagate = False
    try:
        yield handler
    finally:
        LOGGER.removeHandler(handler)
        LOGGER.setLevel(previous[0])
        LOGGER.propagate = previous[1]
        handler.close()
