"""How long steps report progress without knowing how it is shown.

A ``Progress`` is told how many more steps (tiles, epochs, iterations) are done. Code that knows
a stage's size but not how it is displayed takes ``Bars``: it opens one progress display for
``total`` steps under ``label`` and gets that display's ``Progress`` back. The CLI's ``Bars``
draws tqdm bars; the render worker prints lines (Blender's Python has no tqdm).
"""

from __future__ import annotations

from typing import Callable

Progress = Callable[[int], None]
Bars = Callable[[str, int], Progress]
