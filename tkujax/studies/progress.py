"""A one-line progress report on a stream (stderr by default): done/total, rate, ETA."""

from __future__ import annotations

import sys
import time


class Progress:
    """A one-line progress report on stderr: pushes done, pushes/s, ETA."""

    def __init__(self, total: int, done: int, stream=sys.stderr):
        self.total, self.done, self.stream = total, done, stream
        self.t0, self.done0 = time.perf_counter(), done

    def restart(self) -> None:
        self.t0, self.done0 = time.perf_counter(), self.done

    def note(self, text: str) -> None:
        print(f"\r{text}", end="", file=self.stream, flush=True)

    def update(self, n: int) -> None:
        self.done += n
        dt = time.perf_counter() - self.t0
        rate = (self.done - self.done0) / dt if dt > 0 and self.done > self.done0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        pct = 100.0 * self.done / max(self.total, 1)
        print(f"\rpushes {self.done}/{self.total} ({pct:5.1f}%)  {rate:8.1f} pushes/s  "
              f"ETA {eta:6.0f} s   ", end="", file=self.stream, flush=True)

    def close(self) -> None:
        print(file=self.stream, flush=True)
