"""What walking-sweep tests share: one spec run to the full horizon and with early decisions."""

from __future__ import annotations


def full_and_early(data: dict, folder) -> dict:
    """{"full": records, "early": records} of the sweep spec `data` (a dict) on MJX, each run
    into its own subfolder of `folder`."""
    from tkujax.dialects.sweep_spec import parse_spec
    from tkujax.sweeps.sweep import load, run_sweep

    out = {}
    for mode in ("full", "early"):
        run_sweep(parse_spec(data), folder / mode, backend="mjx", quiet=True, decisions=mode)
        out[mode] = load(folder / mode)
    return out
