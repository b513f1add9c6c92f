"""How a command ends when it cannot go on: one line on stderr and an exit code.

- bad input (a CLI value, a spec key, a parameter): "tkujax CMD: error: KEY: ... allowed ...",
  exit 2 (argparse's own errors too, without the usage block: `OneLineParser`);
- an OS error (a file in the way, no permission, a name too long): the path and what is wrong,
  exit 2;
- Ctrl-C: "interrupted; rerun the same command to resume" (`RESUMES`; a command whose rerun
  does something else says what, `run_command`'s rerun), exit 130 (128 + SIGINT), no
  traceback; the sweep's writers remove their temporary files on the way out
  (`tkujax.sweeps.chunks`).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
RESUMES = "rerun the same command to resume"


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line naming the option (exit 2)."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {one_line(message)} (see {self.prog} "
                                  "-h)\n")


def bounded_int(lo: int, hi: int):
    """An argparse type: an integer in [lo, hi], else an error naming the range."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], "
                                             f"got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], got {value}")
        return value
    parse.__name__ = f"integer in [{lo}, {hi}]"
    return parse


def one_line(text: str) -> str:
    """`text` on one line (its line breaks as '; ')."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


def os_error_text(err: OSError) -> str:
    """The path(s) of an OSError and what is wrong with them."""
    if err.filename is None:
        return one_line(str(err))
    paths = f"{err.filename}" + (f" -> {err.filename2}" if err.filename2 else "")
    if isinstance(err, FileExistsError) and os.path.lexists(err.filename) \
            and not os.path.isdir(err.filename):       # a folder wanted where a file is
        return f"{paths}: not a folder (a file has that name)"
    return f"{paths}: {one_line(err.strerror or str(err))}"


# A Ctrl-C that lands where Python drops exceptions is delivered again this much later.
REDELIVER_S = 0.05
# The re-deliveries not yet made: a command that has ended as interrupted cancels them, else
# one landing while Python exits would end the process by SIGINT instead of exit 130
# (tests/test_hostile_interrupts.py).
PENDING_REDELIVERIES: list[threading.Timer] = []
# Set once a command has ended as interrupted (cleared when one starts): a Ctrl-C already on
# its way then schedules no re-delivery (one would land after the command's last line, while
# Python exits).
INTERRUPT_HANDLED = threading.Event()


def keep_interrupts() -> None:
    """Ctrl-C never lost: Python prints and drops an exception raised where nothing can catch
    it (a garbage-collection callback, such as JAX's, or a __del__: "Exception ignored in
    ..."), so a KeyboardInterrupt landing there would be ignored and the command run on. This
    hook sends SIGINT again shortly after, without the traceback; other such exceptions go to
    the previous hook."""
    if getattr(sys.unraisablehook, "keeps_interrupts", False):
        return
    previous = sys.unraisablehook

    def hook(info):
        if info.exc_type is not None and issubclass(info.exc_type, KeyboardInterrupt):
            if INTERRUPT_HANDLED.is_set():
                return
            timer = threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signal.SIGINT))
            timer.daemon = True
            PENDING_REDELIVERIES.append(timer)
            timer.start()
            return
        previous(info)

    hook.keeps_interrupts = True
    sys.unraisablehook = hook


@contextlib.contextmanager
def interrupts_deferred():
    """A Ctrl-C within the block takes effect at its end (KeyboardInterrupt then): for imports
    of extension modules, which a KeyboardInterrupt in their initialisation turns into an
    ImportError or an abort (jaxlib's)."""
    got = []
    try:
        previous = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    except ValueError:            # not the main thread: signals go to the main thread anyway
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if got:
        raise KeyboardInterrupt


def run_command(name: str, command, rerun=None) -> int:
    """`command()`'s exit code, or the one line and code of the error that ended it. rerun:
    what a rerun of an interrupted command does, a callable asked after the Ctrl-C (None:
    `RESUMES`)."""
    keep_interrupts()
    INTERRUPT_HANDLED.clear()
    try:
        return command()
    except KeyboardInterrupt:
        return _interrupted(name, rerun)
    except Exception as err:
        if from_interrupt(err):
            return _interrupted(name, rerun)
        if isinstance(err, OSError):
            print(f"{name}: error: {os_error_text(err)}", file=sys.stderr)
            return EXIT_BAD_INPUT
        if isinstance(err, (ValueError, OverflowError)):   # bad input: the message names the key
            print(f"{name}: error: {one_line(str(err))}", file=sys.stderr)
            return EXIT_BAD_INPUT
        raise


def cancel_redeliveries() -> None:
    """Cancel the Ctrl-C re-deliveries not yet made (`keep_interrupts`)."""
    while PENDING_REDELIVERIES:
        PENDING_REDELIVERIES.pop().cancel()


def _interrupted(name: str, rerun=None) -> int:
    INTERRUPT_HANDLED.set()
    cancel_redeliveries()
    try:
        said = RESUMES if rerun is None else rerun()
    except (OSError, ValueError):     # the line comes out whatever the command left behind
        said = RESUMES
    print(f"{name}: interrupted; {said}", file=sys.stderr)
    return EXIT_INTERRUPTED


def from_interrupt(err: BaseException) -> bool:
    """Whether a Ctrl-C caused `err`: an extension module whose import it cut short raises
    ImportError from the KeyboardInterrupt (numpy's, while JAX loads)."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def bounded_float(lo: float, hi: float):
    """An argparse type: a finite number in [lo, hi], else an error naming the range."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in [{lo:g}, {hi:g}], "
                                             f"got {text!r}") from None
        if not lo <= value <= hi:      # NaN fails every comparison
            raise argparse.ArgumentTypeError(f"expected a number in [{lo:g}, {hi:g}], got {text}")
        return value
    parse.__name__ = f"number in [{lo:g}, {hi:g}]"
    return parse
