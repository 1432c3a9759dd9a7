"""The wall time a report states: the run's, up to the moment its report is written."""

from __future__ import annotations

import time


class WallTime:
    """Stands in a report's text for the run's wall time and is filled in when the text is
    written: drawing a full run's figures takes a minute or more, and is part of the run."""

    MARK = "\x00wall-time\x00"

    def __init__(self, seconds: float):
        self.seconds = seconds  # the run's time before its report
        self.t0 = time.perf_counter()

    def fill(self, text: str) -> str:
        return text.replace(self.MARK, f"{self.seconds + time.perf_counter() - self.t0:.0f}")
