"""How long steps report progress without knowing how it is shown.

A ``Progress`` is told how many more steps (tiles, epochs, iterations) are done. Code that knows
a stage's size but not how it is displayed takes ``Bars``: it opens one progress display for
``total`` steps under ``label`` and gets that display's ``Progress`` back. The CLI's ``Bars``
draws tqdm bars on a terminal and ``LineBar`` lines in a log; the render worker prints lines
(Blender's Python has no tqdm).
"""

from __future__ import annotations

import sys
import time
from typing import Callable

Progress = Callable[[int], None]
Bars = Callable[[str, int], Progress]


class LineBar:
    """What a progress bar becomes when stderr is not a terminal (a farm's log file, CI): a plain line
    every ``every`` seconds and one at the end, instead of carriage returns a log cannot show."""

    def __init__(self, total: int, desc: str, unit: str = "it", initial: int = 0, every: float = 30.0,
                 stream=None):
        self.total, self.desc, self.unit, self.n, self.every = total, desc, unit, initial, every
        self.stream = stream if stream is not None else sys.stderr
        self.started = self.last = time.monotonic()
        self.closed = False

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.every:
            self.last = now
            self._line()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._line()

    def _line(self) -> None:
        elapsed = time.monotonic() - self.started
        share = f"{self.n / self.total:.0%} " if self.total else ""
        print(f"{self.desc}: {share}{self.n}/{self.total} {self.unit} [{elapsed:.0f} s]", file=self.stream,
              flush=True)

    def __enter__(self) -> "LineBar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def on_terminal() -> bool:
    """Whether progress goes to a terminal (draw bars) or to a log (print ``LineBar`` lines)."""
    return sys.stderr.isatty()
