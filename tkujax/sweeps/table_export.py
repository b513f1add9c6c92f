"""A finished sweep's records as one Parquet (or CSV) file, and reading such a file back.

`export_records(DIR)` writes every verified chunk of a complete sweep folder, the same columns
`tkujax.load(DIR)` returns, to one Parquet file through pyarrow. The file's schema metadata
holds the sweep's manifest (JSON, key `MANIFEST_KEY`) and each column's NumPy dtype and row
shape (`DTYPES_KEY`), so that `load(FILE)` returns the very arrays `load(DIR)` does. Any
Parquet reader (DuckDB, polars, pandas, Spark) reads the records as a plain table:

    duckdb.sql("SELECT avg(fell::INT) FROM 'sweep.parquet' WHERE control")

CSV is written for spreadsheets; it has no metadata, so the manifest goes beside it
(`FILE.manifest.json`) and a column with several values per record becomes one column per
value (`name[0]`, `name[1]`, ...).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tkujax.sweeps import chunks
from tkujax.sweeps import sweep as sweep_records
from tkujax.sweeps.sweep_state import (IncompleteSweep, SweepRecords, SweepState,
                                       require_complete)

MANIFEST_KEY = b"tkujax.manifest"
DTYPES_KEY = b"tkujax.dtypes"
FORMATS = ("parquet", "csv")
# The exported manifest's note of how complete the sweep was (`SweepState.describe`).
EXPORTED_KEY = "exported_state"

__all__ = ["DTYPES_KEY", "EXPORTED_KEY", "FORMATS", "MANIFEST_KEY", "IncompleteSweep",
           "default_output", "export_records", "exported_state", "finished_manifest",
           "is_parquet", "load", "read_parquet", "records_table"]


def _pyarrow():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as err:     # a dependency; only a broken install lacks it
        raise ImportError("Parquet export needs pyarrow: pip install pyarrow") from err
    return pa, pq


def finished_manifest(run_dir: str | Path, allow_incomplete: bool = False) -> dict:
    """The manifest of a complete sweep folder; IncompleteSweep (a one-line reason naming the
    folder and "incomplete: k of n chunks") else, unless allow_incomplete: then the manifest
    with the sweep's state added (`EXPORTED_KEY`: complete, chunks_done, n_chunks)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir} is not a folder")
    manifest = chunks.read_manifest(run_dir)
    if not manifest:
        raise IncompleteSweep(f"{run_dir} has no manifest.json: not a sweep folder")
    state = require_complete(run_dir, allow_incomplete, "tkujax export")
    return manifest if state.complete else manifest | {EXPORTED_KEY: state.describe()}


def default_output(run_dir: str | Path, fmt: str = "parquet") -> Path:
    """Where `export_records` writes by default: beside the folder, `DIR.parquet`."""
    run_dir = Path(run_dir)
    return run_dir.with_name(run_dir.name + "." + fmt)


def records_table(cols: dict[str, np.ndarray], manifest: dict):
    """The records as a pyarrow Table, the manifest and the columns' dtypes in its metadata.
    A column with several values per record is a fixed-size list column."""
    pa, _ = _pyarrow()
    arrays, dtypes = {}, {}
    for name, col in cols.items():
        col = np.asarray(col)
        dtypes[name] = {"dtype": col.dtype.str, "shape": list(col.shape[1:])}
        if col.ndim == 1:
            arrays[name] = pa.array(col)
        else:
            width = int(np.prod(col.shape[1:]))
            flat = pa.array(np.ascontiguousarray(col).reshape(-1))
            arrays[name] = pa.FixedSizeListArray.from_arrays(flat, width)
    table = pa.table(arrays)
    meta = {MANIFEST_KEY: json.dumps(manifest, sort_keys=True).encode(),
            DTYPES_KEY: json.dumps(dtypes).encode()}
    return table.replace_schema_metadata(meta)


def _csv_columns(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    flat = {}
    for name, col in cols.items():
        col = np.asarray(col)
        if col.ndim == 1:
            flat[name] = col
            continue
        wide = col.reshape(len(col), -1)
        for j in range(wide.shape[1]):
            flat[f"{name}[{j}]"] = wide[:, j]
    return flat


def _replace(tmp: Path, path: Path) -> Path:
    os.replace(tmp, path)
    return path


def export_records(run_dir: str | Path, out: str | Path | None = None,
                   fmt: str = "parquet", allow_incomplete: bool = False) -> Path:
    """Write a finished sweep's records (all chunks, verified) to one file; returns its path.

    fmt: "parquet" (the manifest in the schema metadata) or "csv" (the manifest beside it as
    OUT.manifest.json). out: default `DIR.parquet` (or `DIR.csv`) beside the folder. The file
    is written to a temporary name and renamed, so a reader never sees half of it. An
    incomplete sweep raises IncompleteSweep (a ValueError) and writes nothing, unless
    allow_incomplete: then the chunks done are written and the manifest's EXPORTED_KEY says
    "incomplete" (`load(FILE)`'s state)."""
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    manifest = finished_manifest(run_dir, allow_incomplete)
    cols = sweep_records.load(run_dir)
    path = Path(out) if out is not None else default_output(run_dir, fmt)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pa, pq = _pyarrow()
    if fmt == "parquet":
        pq.write_table(records_table(cols, manifest), tmp)
        return _replace(tmp, path)
    from pyarrow import csv

    csv.write_csv(pa.table(_csv_columns(cols)), tmp)
    side = path.with_name(path.name + ".manifest.json")
    side_tmp = side.with_name(f".{side.name}.{os.getpid()}.tmp")
    side_tmp.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    _replace(side_tmp, side)
    return _replace(tmp, path)


def is_parquet(path: str | Path) -> bool:
    """A file that starts with Parquet's magic bytes."""
    path = Path(path)
    if not path.is_file():
        return False
    with path.open("rb") as f:
        return f.read(4) == b"PAR1"


def _column(table, name: str, spec: dict | None) -> np.ndarray:
    col = table.column(name).combine_chunks()
    if spec is None:
        return col.to_numpy(zero_copy_only=False)
    shape = tuple(spec["shape"])
    if shape:
        col = col.flatten()
    arr = col.to_numpy(zero_copy_only=False).astype(np.dtype(spec["dtype"]), copy=False)
    return arr.reshape((-1, *shape)) if shape else arr


def read_parquet(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """The records (dict of NumPy columns, dtypes as the sweep wrote them) and the manifest of
    a file written by `export_records` (a Parquet file of another writer: its columns as
    pyarrow converts them, and an empty manifest)."""
    _, pq = _pyarrow()
    table = pq.read_table(path)
    meta = table.schema.metadata or {}
    manifest = json.loads(meta[MANIFEST_KEY]) if MANIFEST_KEY in meta else {}
    dtypes = json.loads(meta[DTYPES_KEY]) if DTYPES_KEY in meta else {}
    cols = {name: _column(table, name, dtypes.get(name)) for name in table.column_names}
    return cols, manifest


def load(path: str | Path, as_frame: bool = False):
    """A sweep's verified records as a dict of columns (or, with as_frame=True, a pandas
    DataFrame): from a sweep folder (`tkujax.sweeps.sweep.load`) or from a Parquet file that
    `tkujax export` wrote, which gives the same columns, dtypes and rows. Either says how
    complete the sweep was: the dict's `state` and `complete` (`SweepRecords`), the
    DataFrame's attrs."""
    if not is_parquet(path):
        return sweep_records.load(path, as_frame=as_frame)
    cols, manifest = read_parquet(path)
    return sweep_records.as_frame_if(SweepRecords(cols, exported_state(path, manifest)),
                                     as_frame)


def exported_state(path: str | Path, manifest: dict) -> SweepState | None:
    """The state of the sweep a file of `export_records` holds (None: another writer's file;
    without EXPORTED_KEY: a complete sweep, the only kind exported without it)."""
    if not manifest:
        return None
    n = int(manifest.get("n_chunks", 0))
    note = manifest.get(EXPORTED_KEY, dict(chunks_done=n, n_chunks=n))
    return SweepState(str(path), int(note["chunks_done"]), int(note["n_chunks"]))
