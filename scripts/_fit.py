"""Shared by the calibration research scripts: read one fitted set from a calibration summary,
and the output guard (an explicit --out that never names the input)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def parser(doc: str, out_help: str) -> argparse.ArgumentParser:
    """calibration (the summary JSON), which (its fit: ALL, T4, ...) and a required --out."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("calibration", type=Path, help="calibration summary JSON (calibration.json)")
    ap.add_argument("which", help="the fit inside it: ALL, T4, ...")
    ap.add_argument("--out", type=Path, required=True, help=out_help)
    return ap


def check_out(ap: argparse.ArgumentParser, inputs: list[Path], out: Path) -> Path:
    """`out`, refused (argparse error, exit 2) where it is one of the inputs: a script never
    overwrites what it reads."""
    for path in inputs:
        if path is not None and out.resolve() == Path(path).resolve():
            ap.error(f"--out {out} is the input {path}; choose another output file")
    return out


def load_fit(path: Path, which: str) -> dict:
    """The fit `which` of the calibration summary at `path`: {"x", "reading", "rows", ...}."""
    summary = json.loads(Path(path).read_text())
    if which not in summary or "x" not in summary[which]:
        fits = sorted(k for k, v in summary.items() if isinstance(v, dict) and "x" in v)
        raise SystemExit(f"{path}: no fit {which!r}; fits there: {fits}")
    return summary[which]


def fit_params(path: Path, which: str):
    """(x, reading, ModelParams, ControllerParams) of the fit `which` in the summary at `path`."""
    from tkujax.studies.calibrate import fit_vector as P

    fit = load_fit(path, which)
    x, reading = fit["x"], fit["reading"]
    mp = P.model_params(x)
    return x, reading, mp, P.controller_params(x, reading, mp)


def write_json(out: Path, data) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1))
