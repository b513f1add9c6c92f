"""Progress of long commands on stderr: tqdm bars with the time left, on a terminal only.

- `Progress`: a count (the sweep's pushes: `tkujax sweep`, `tkujax capture`): done/total,
  rate and the time left, the rate counted from `restart()` (after the first compile).
- `track(iterable)`: a bar over a loop (bench stages, tuning runs).
- `StatusLog`: the log function of a study (`tkujax tune`, `tkujax calibrate`, `tkujax
  bench`): its lines scroll above a bar of the elapsed time against the study's budget and
  the time left.

A bar is drawn only where its stream is a terminal. Elsewhere (CI, a log file, a pipe)
`Progress` and `track` print nothing and `StatusLog` prints its lines as plain lines.
`TKUJAX_PROGRESS=1` draws the bars on any stream, `TKUJAX_PROGRESS=0` on none.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator

from tqdm import tqdm

PROGRESS_ENV = "TKUJAX_PROGRESS"
COUNT_FORMAT = ("{desc}{percentage:5.1f}%|{bar}| {n_fmt}/{total_fmt} {unit} "
                "[{elapsed}, ETA {remaining}, {rate_fmt}]")
BUDGET_FORMAT = "{desc}|{bar}| "
OPEN_FORMAT = "{desc}[{elapsed}]"

__all__ = ["PROGRESS_ENV", "Progress", "StatusLog", "bar_wanted", "track"]


def bar_wanted(stream) -> bool:
    """Whether to draw a bar on `stream`: TKUJAX_PROGRESS=1 / 0 decide; else only on a
    terminal."""
    forced = os.environ.get(PROGRESS_ENV, "").strip().lower()
    if forced in ("1", "true", "yes", "on"):
        return True
    if forced in ("0", "false", "no", "off"):
        return False
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:            # a closed stream
        return False


class Progress:
    """A count of work done out of `total` (`done` of it finished before this run), as a bar
    on a terminal with the rate and the time left; silent on any other stream.

    `update(n)` adds n; `note(text)` shows what runs before the first unit is done (the first
    compile); `restart()` counts the rate and the time left from now on (so that they exclude
    the compile); `close()` ends the bar. `done` always holds the count."""

    def __init__(self, total: int, done: int = 0, stream=None, unit: str = "pushes",
                 desc: str = "", bar: bool | None = None):
        self.total, self.done, self.unit = int(total), int(done), unit
        self.stream = sys.stderr if stream is None else stream
        self.desc = desc
        self.t0, self.done0 = time.perf_counter(), self.done
        self.bar = None
        if bar_wanted(self.stream) if bar is None else bar:
            self.bar = tqdm(total=self.total, initial=self.done, unit=unit, file=self.stream,
                            desc=desc or None, smoothing=0, dynamic_ncols=True,
                            bar_format=COUNT_FORMAT, mininterval=0.2)

    @property
    def rate(self) -> float:
        """Units per second since the start or the last restart() (0 before any)."""
        dt = time.perf_counter() - self.t0
        return (self.done - self.done0) / dt if dt > 0 and self.done > self.done0 else 0.0

    @property
    def eta_s(self) -> float:
        """Seconds left at the current rate (nan before the rate is known)."""
        rate = self.rate
        return (self.total - self.done) / rate if rate > 0 else float("nan")

    def restart(self) -> None:
        self.t0, self.done0 = time.perf_counter(), self.done
        if self.bar is not None:
            self.bar.reset(total=self.total)
            self.bar.initial = self.bar.n = self.bar.last_print_n = self.done
            self.bar.refresh()

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_description_str(text)

    def update(self, n: int) -> None:
        self.done += int(n)
        if self.bar is not None:
            if self.bar.desc != (self.desc or ""):
                self.bar.set_description_str(self.desc, refresh=False)
            self.bar.update(int(n))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def track(iterable: Iterable, total: int | None = None, desc: str = "", unit: str = "it",
          stream=None) -> Iterator:
    """The items of `iterable`, with a bar (time left) on a terminal, nothing elsewhere."""
    items = list(iterable) if total is None and not hasattr(iterable, "__len__") else iterable
    n = len(items) if total is None else total
    with Progress(n, 0, stream, unit=unit, desc=desc) as progress:
        for item in items:
            yield item
            progress.update(1)


class StatusLog:
    """A study's log function: `log(line)`. On a terminal each line is written above a bar of
    the time elapsed against `budget_s` (the time left), or of the elapsed time alone when
    there is no budget; elsewhere each line is printed as it is. quiet: nothing at all."""

    def __init__(self, quiet: bool = False, stream=None, budget_s: float | None = None,
                 desc: str = ""):
        self.quiet, self.budget_s = quiet, budget_s
        self.stream = sys.stderr if stream is None else stream
        # monotonic, not perf_counter: the log's clock stays apart from the budget clocks of
        # the stages it reports (tests/test_bench.py fakes perf_counter for those).
        self.t0 = time.monotonic()
        self.lines = 0
        self.bar = None
        if not quiet and bar_wanted(self.stream):
            fmt = BUDGET_FORMAT if budget_s else OPEN_FORMAT
            self.bar = tqdm(total=budget_s or None, file=self.stream, desc=desc or None,
                            bar_format=fmt, dynamic_ncols=True, smoothing=0, leave=False)
            self.tick()

    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def __call__(self, line: str) -> None:
        if self.quiet:
            return
        self.lines += 1
        if self.bar is None:
            print(line, file=self.stream, flush=True)
            return
        self.bar.write(str(line), file=self.stream)
        self.tick()

    def tick(self) -> None:
        """Move the bar to the time elapsed (done by every line)."""
        if self.bar is None:
            return
        t = self.elapsed()
        if self.budget_s:
            self.bar.n = min(t, self.budget_s)
            clock = tqdm.format_interval
            self.bar.bar_format = (BUDGET_FORMAT + f"{clock(t)} of {clock(self.budget_s)} "
                                   f"budget, {clock(max(self.budget_s - t, 0.0))} left")
        else:
            self.bar.n = t
        self.bar.refresh()

    def add_budget(self, seconds: float) -> None:
        """A stage the budget did not foresee (a retry): the bar's budget grows by `seconds`."""
        if self.budget_s:
            self.budget_s += seconds
            if self.bar is not None:
                self.bar.total = self.budget_s
        self.tick()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __del__(self) -> None:
        self.close()
