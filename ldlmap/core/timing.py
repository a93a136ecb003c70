"""The one stage timer of map building, line extraction and localization."""

from __future__ import annotations

import time
from typing import Callable


class StageClock:
    """Seconds per stage: ``clock.lap(name)`` stores the wall seconds since the previous lap (or
    since the clock was made) in ``seconds[key(name)]``, and with ``cpu_seconds`` the process's CPU
    seconds (all threads) in ``cpu_seconds[cpu_key(name)]``."""

    def __init__(self, seconds: dict[str, float], cpu_seconds: dict[str, float] | None = None,
                 key: Callable[[str], str] = str, cpu_key: Callable[[str], str] = str):
        self.seconds, self.cpu_seconds, self.key, self.cpu_key = seconds, cpu_seconds, key, cpu_key
        self.restart()

    def restart(self) -> None:
        """Count the next lap from now."""
        self._wall, self._cpu = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> float:
        """Record stage ``name`` as ended now; returns its wall seconds."""
        wall, cpu = time.perf_counter(), time.process_time()
        self.seconds[self.key(name)] = wall - self._wall
        if self.cpu_seconds is not None:
            self.cpu_seconds[self.cpu_key(name)] = cpu - self._cpu
        elapsed, self._wall, self._cpu = wall - self._wall, wall, cpu
        return elapsed
