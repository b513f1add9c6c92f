"""Whether a sweep folder is complete: one rule for everything that reads one.

`sweep_state(DIR)` counts the chunks whose file matches its manifest entry
(`tkujax.sweeps.chunks.done_chunks`: present, the right size, the recorded sha256) against the
sweep's `n_chunks`; the manifest's own `complete` flag is not trusted (a writer still running,
or a chunk lost since, leaves it stale). `require_complete(DIR, allow_incomplete)` is what every
reader of a sweep folder calls (`tkujax map`, `compare`, `capture`, `export`, `view` and the
library's `make_maps`, `compare_runs`, `export_records`): an incomplete sweep is refused with
IncompleteSweep (a ValueError) naming the folder and "incomplete: k of n chunks"; with
allow_incomplete its state is returned and the reader marks what it writes with `state.mark`.
`tkujax.load` returns the records with their state (`SweepRecords`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from tkujax.sweeps import chunks
from tkujax.dialects.validation import SpecError

ALLOW_FLAG = "--allow-incomplete"


class IncompleteSweep(SpecError):
    """The folder is not a finished sweep (no manifest, or chunks still missing): a ValueError
    (a SpecError, as the readers' other refusals)."""


@dataclasses.dataclass(frozen=True)
class SweepState:
    """How much of the sweep in `folder` is done: chunks whose file matches the manifest."""

    folder: str
    chunks_done: int
    n_chunks: int

    @property
    def complete(self) -> bool:
        return self.n_chunks > 0 and self.chunks_done == self.n_chunks

    @property
    def mark(self) -> str:
        """"" for a complete sweep, else "incomplete: k of n chunks"."""
        return "" if self.complete else f"incomplete: {self.chunks_done} of {self.n_chunks} chunks"

    def describe(self) -> dict:
        return dict(complete=self.complete, chunks_done=self.chunks_done, n_chunks=self.n_chunks)


def sweep_state(folder: str | Path) -> SweepState:
    """The state of the sweep in `folder`; FileNotFoundError when it is no sweep folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder")
    manifest = chunks.read_manifest(folder)
    if not manifest:
        raise FileNotFoundError(f"{folder} holds no sweep ({chunks.MANIFEST} not found)")
    if "n_chunks" not in manifest:   # a folder made by hand: its chunks and its flag
        done = len(list(folder.glob("chunk_*.npz")))
        return SweepState(str(folder), done, done + (not manifest.get("complete", False)))
    n_chunks = int(manifest["n_chunks"])
    if "chunks" not in manifest:     # written before the manifest held checksums: the files
        done = sum((folder / chunks.chunk_name(i)).is_file() for i in range(n_chunks))
    else:
        done = len(chunks.done_chunks(folder, n_chunks))
    return SweepState(str(folder), done, n_chunks)


def refusal(state: SweepState, reader: str) -> str:
    """The one-line refusal of `reader` (a command's name) to read an incomplete sweep."""
    return (f"{state.folder} is an incomplete sweep ({state.mark}): rerun the sweep command "
            f"to finish it, or pass {ALLOW_FLAG} to {reader} to read it marked as such")


def require_complete(folder: str | Path, allow_incomplete: bool = False,
                     reader: str = "tkujax") -> SweepState:
    """The sweep's state; IncompleteSweep (refusal's message) when it is incomplete and
    allow_incomplete is False."""
    state = sweep_state(folder)
    if not state.complete and not allow_incomplete:
        raise IncompleteSweep(refusal(state, reader))
    return state


class SweepRecords(dict):
    """A sweep's records (a dict of columns, as before) that says how complete the sweep was:
    `state` (a SweepState; None for a file of another writer) and `complete`."""

    def __init__(self, columns: dict, state: SweepState | None):
        super().__init__(columns)
        self.state = state

    @property
    def complete(self) -> bool | None:
        return None if self.state is None else self.state.complete
