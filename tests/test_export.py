"""`tkujax export`: a finished sweep's records as one Parquet (or CSV) file that `tkujax.load`
and DuckDB read back to the same records; an incomplete sweep is refused."""

import json
from pathlib import Path

import duckdb
import numpy as np
import pyarrow.parquet as pq
import pytest

import tkujax
from tkujax.cli import main
from tkujax.sweeps.table_export import DTYPES_KEY, MANIFEST_KEY, read_parquet, records_table

TINY = str(Path(__file__).resolve().parents[1] / "specs" / "sweep" / "tiny.toml")


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export") / "tiny"
    assert main(["sweep", TINY, "--out", str(out), "--backend", "mujoco"]) == 0
    return out


def _same_records(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for k in a:
        assert a[k].dtype == b[k].dtype, k
        assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k


def test_parquet_holds_the_records_and_the_manifest(sweep_dir, capsys):
    out = sweep_dir.parent / "records.parquet"
    assert main(["export", str(sweep_dir), "--format", "parquet", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    folder = tkujax.load(sweep_dir)
    _same_records(folder, tkujax.load(out))
    meta = pq.read_schema(out).metadata
    manifest = json.loads((sweep_dir / "manifest.json").read_text())
    assert json.loads(meta[MANIFEST_KEY]) == manifest and manifest["complete"]
    assert read_parquet(out)[1] == manifest
    assert DTYPES_KEY in meta

    con = duckdb.connect()
    rate = con.execute(f"SELECT avg(fell::INT) FROM '{out}'").fetchone()[0]
    assert rate == pytest.approx(folder["fell"].mean()) and 0 < rate < 1
    by_control = dict(con.execute(f"SELECT control, avg(fell::INT) FROM '{out}' "
                                  "GROUP BY control").fetchall())
    for on in (False, True):
        assert by_control[on] == pytest.approx(folder["fell"][folder["control"] == on].mean())
    table = con.execute(f"SELECT * FROM '{out}' ORDER BY push_id").fetchnumpy()
    order = np.argsort(folder["push_id"])
    for k, v in folder.items():
        got = np.asarray(table[k]).astype(v.dtype)
        assert np.array_equal(got, v[order], equal_nan=v.dtype.kind == "f"), k


def test_load_as_frame_is_the_same_from_parquet(sweep_dir):
    pd = pytest.importorskip("pandas")
    out = sweep_dir.parent / "frame.parquet"
    assert main(["export", str(sweep_dir), "--out", str(out)]) == 0
    pd.testing.assert_frame_equal(tkujax.load(sweep_dir, as_frame=True),
                                  tkujax.load(out, as_frame=True))


def test_default_output_sits_beside_the_folder(sweep_dir):
    assert main(["export", str(sweep_dir)]) == 0
    assert (sweep_dir.parent / "tiny.parquet").is_file()
    assert not list(sweep_dir.glob("*.parquet"))


def test_csv_has_the_columns_and_the_manifest_beside_it(sweep_dir):
    out = sweep_dir.parent / "records.csv"
    assert main(["export", str(sweep_dir), "--format", "csv", "--out", str(out)]) == 0
    folder = tkujax.load(sweep_dir)
    rows = duckdb.connect().execute(f"SELECT * FROM read_csv_auto('{out}') "
                                    "ORDER BY push_id").fetchnumpy()
    assert list(rows) == list(folder)
    assert np.array_equal(np.asarray(rows["fell"]), folder["fell"][np.argsort(folder["push_id"])])
    side = json.loads(Path(str(out) + ".manifest.json").read_text())
    assert side == json.loads((sweep_dir / "manifest.json").read_text())


def test_incomplete_sweep_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "partial"
    assert main(["sweep", TINY, "--out", str(out), "--backend", "mujoco",
                 "--max-chunks", "1"]) == 0
    capsys.readouterr()
    target = tmp_path / "partial.parquet"
    assert main(["export", str(out), "--out", str(target)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tkujax export: error:") and "incomplete sweep" in err
    assert "\n" not in err
    assert not target.exists() and not list(tmp_path.glob(".*.tmp"))
    assert main(["export", str(tmp_path / "nowhere")]) == 2
    assert main(["export", str(tmp_path)]) == 2             # a folder without a manifest


def test_columns_with_several_values_per_record_round_trip(tmp_path):
    cols = {"push_id": np.arange(3), "step_xy": np.arange(12, dtype=np.float32).reshape(3, 2, 2),
            "fell": np.array([True, False, True])}
    path = tmp_path / "wide.parquet"
    pq.write_table(records_table(cols, {"name": "wide"}), path)
    got, manifest = read_parquet(path)
    _same_records(cols, got)
    assert manifest == {"name": "wide"}
