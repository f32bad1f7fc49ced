"""Wall-clock time of a command's stages, for its report."""

from __future__ import annotations

import time

# the name of a command's compile stage when every program came from the
# cache: its seconds are then installing them, not compiling
COMPILED_EARLIER = "programs from the cache (compiled earlier)"


class Stopwatch:
    """``lap(name)`` records the seconds since the previous lap (or the start)."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> float:
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self._last
        self._last = now
        return self.laps[name]
