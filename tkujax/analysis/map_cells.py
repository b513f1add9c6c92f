"""The binned statistics of sweep records behind the stability maps: axes of azimuth, impulse
and phase bins, fall fractions per cell, fall boundaries (the impulse where the fall fraction
crosses 1/2), per ensemble member and by the push's phase in the control period.

A velocity-kick sweep's axis is its kick_mps column in place of the impulse (`push_size`, the
one definition of the push's size column and label).

Diverged records (numerical blow-up) are neither fell nor survived: every cell and fraction
leaves them out. Pure functions of the record columns (`tkujax.sweeps.sweep.load`); the
figures and files are `tkujax.analysis.maps`'s.
"""

from __future__ import annotations

import numpy as np

from tkujax.sim.push import onset_phase
from tkujax.dialects.kick_table import KICK_KEY
from tkujax.dialects.sweep_spec import PHASE_KEY

ROUND = 6
MAX_AZIMUTH_BINS = 72     # 5 deg
MAX_IMPULSE_BINS = 48
MAX_PHASE_BINS = 15      # 2 ms: the physics time step
MIN_MEMBER_PUSHES = 6    # records of a member at an azimuth (one control setting) for its boundary
MIN_BAND_MEMBERS = 3     # members with a boundary at an azimuth for the band there
BAND_QUANTILES = (0.1, 0.5, 0.9)


def push_size(rec: dict) -> tuple[str, str]:
    """(the push's size column, its axis label): kick_mps, "kick (m/s)" for velocity kicks
    (`tkujax.dialects.kick_table`), else impulse_ns, "impulse (N·s)"."""
    return (KICK_KEY, "kick (m/s)") if KICK_KEY in rec else ("impulse_ns", "impulse (N·s)")


def bin_axis(values: np.ndarray, max_bins: int, period: float | None = None,
             keep_empty: bool = False):
    """(bin centres, bin index of each value). Grid values map to themselves; when there are
    more distinct values than max_bins (random samples), equal bins centred on a regular grid
    (for a periodic axis, centred on 0). Empty bins are dropped unless keep_empty (then they
    are drawn blank, so a sparse run's cells do not stretch over the gaps)."""
    values = np.round(np.asarray(values, float), ROUND)
    uniq = np.unique(values)
    if len(uniq) <= max_bins:
        return uniq, np.searchsorted(uniq, values)
    if period is not None:
        width = period / max_bins
        idx = np.floor(np.mod(values + width / 2, period) / width).astype(int) % max_bins
        centres = np.arange(max_bins) * width
    else:
        centres = np.linspace(uniq[0], uniq[-1], max_bins)
        width = centres[1] - centres[0]
        idx = np.clip(np.round((values - centres[0]) / width).astype(int), 0, max_bins - 1)
    if keep_empty:
        return centres, idx
    used = np.unique(idx)             # drop empty bins
    return centres[used], np.searchsorted(used, idx)


def cell_means(rec: dict, key: str, control: bool):
    """(azimuths, impulses (or kicks: `push_size`), mean of rec[key] per cell as (n_az, n_J)),
    NaN where empty."""
    sel = rec["control"].astype(bool) == control
    if "diverged" in rec:
        sel &= ~rec["diverged"].astype(bool)
    azs, ia = bin_axis(np.mod(rec["azimuth_deg"][sel], 360.0), MAX_AZIMUTH_BINS, 360.0)
    js, ij = bin_axis(rec[push_size(rec)[0]][sel], MAX_IMPULSE_BINS)
    v = rec[key][sel].astype(float)
    total = np.zeros((len(azs), len(js)))
    count = np.zeros_like(total)
    ok = np.isfinite(v)
    np.add.at(total, (ia[ok], ij[ok]), v[ok])
    np.add.at(count, (ia, ij), ok.astype(float))
    with np.errstate(invalid="ignore"):
        return azs, js, np.where(count > 0, total / np.maximum(count, 1), np.nan)


def max_recoverable_impulse(rec: dict, control: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per azimuth: the largest impulse below which every tested impulse was survived
    (fall fraction < 1/2); 0 when even the smallest fell."""
    azs, js, frac = cell_means(rec, "fell", control)
    out = np.zeros(len(azs))
    for i in range(len(azs)):
        fell = frac[i] >= 0.5
        first = np.argmax(fell) if fell.any() else len(js)
        out[i] = js[first - 1] if first > 0 else 0.0
    return azs, out


def _boundary_of_tested(js: np.ndarray, frac: np.ndarray) -> float:
    """max_recoverable_impulse's definition over the tested cells only (frac NaN: untested):
    the largest tested impulse below the first whose fall fraction is >= 1/2; 0 when the
    smallest tested one fell; the largest tested when none fell."""
    tested = np.isfinite(frac)
    jt, ft = js[tested], frac[tested]
    fell = ft >= 0.5
    first = int(np.argmax(fell)) if fell.any() else len(jt)
    return float(jt[first - 1]) if first > 0 else 0.0


def half_fall_impulse(rec: dict, control: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per azimuth bin: the impulse (N s) where the fall fraction first reaches 1/2, linear
    between the tested impulse bins (`cell_means`); the smallest tested impulse when it
    already falls half the time, inf when no tested impulse does. Only a sweep's grid
    records count when it has random ones too (`from_grid`)."""
    if "from_grid" in rec:
        grid = np.asarray(rec["from_grid"]).astype(bool)
        rec = {k: np.asarray(v)[grid] for k, v in rec.items()
               if np.ndim(v) and len(v) == len(grid)}
    azs, js, frac = cell_means(rec, "fell", control)
    out = np.full(len(azs), np.inf)
    for i in range(len(azs)):
        tested = np.isfinite(frac[i])
        jt, ft = js[tested], frac[i][tested]
        above = np.flatnonzero(ft >= 0.5)
        if len(above) == 0:
            continue
        k = int(above[0])
        out[i] = jt[0] if k == 0 else jt[k - 1] + (0.5 - ft[k - 1]) / (ft[k] - ft[k - 1]) * (
            jt[k] - jt[k - 1])
    return azs, out


def member_boundaries(rec: dict, control: bool, min_pushes: int = MIN_MEMBER_PUSHES,
                      min_members: int = MIN_BAND_MEMBERS) -> dict:
    """The fall boundary of each ensemble member (rec["robot_id"]) and their spread.

    Azimuth and impulse bins are the map's (`cell_means` over every member's records); a member's
    boundary at an azimuth is `_boundary_of_tested` over its own cells there, NaN where it has
    fewer than `min_pushes` records at that azimuth. q10 / median / q90: np.quantile (linear) of
    the members' boundaries at each azimuth where at least `min_members` have one (else NaN).
    Returns dict(azimuth_deg, impulse_ns (bins), members, boundary (members, azimuths), pushes
    (members, azimuths), n_members (per azimuth), q10, median, q90)."""
    sel = rec["control"].astype(bool) == control
    if "diverged" in rec:
        sel &= ~rec["diverged"].astype(bool)
    azs, ia = bin_axis(np.mod(rec["azimuth_deg"][sel], 360.0), MAX_AZIMUTH_BINS, 360.0)
    js, ij = bin_axis(rec[push_size(rec)[0]][sel], MAX_IMPULSE_BINS)
    rid = np.asarray(rec["robot_id"])[sel].astype(int)
    fell = rec["fell"][sel].astype(float)
    members = np.unique(rid[rid >= 0])
    boundary = np.full((len(members), len(azs)), np.nan)
    pushes = np.zeros((len(members), len(azs)), int)
    for m, member in enumerate(members):
        s = rid == member
        total = np.zeros((len(azs), len(js)))
        count = np.zeros_like(total)
        np.add.at(total, (ia[s], ij[s]), fell[s])
        np.add.at(count, (ia[s], ij[s]), 1.0)
        pushes[m] = count.sum(1).astype(int)
        with np.errstate(invalid="ignore"):
            frac = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        for a in range(len(azs)):
            if pushes[m, a] >= min_pushes:
                boundary[m, a] = _boundary_of_tested(js, frac[a])
    n_members = np.isfinite(boundary).sum(0)
    q = np.full((len(BAND_QUANTILES), len(azs)), np.nan)
    for a in np.flatnonzero(n_members >= max(min_members, 1)):
        b = boundary[:, a]
        q[:, a] = np.quantile(b[np.isfinite(b)], BAND_QUANTILES)
    return dict(azimuth_deg=azs, impulse_ns=js, members=members, boundary=boundary,
                pushes=pushes, n_members=n_members, q10=q[0], median=q[1], q90=q[2],
                min_pushes=min_pushes, min_members=min_members)


def fall_by_phase(rec: dict, variant_keys: tuple[str, ...] = ()) -> dict:
    """Fall fraction per phase bin, per (control, controller-grid point).

    Returns {"phases": bin centres, "rows": [(label, fall fractions (n_phase,), counts)]},
    everything else (impulse, azimuth, ...) marginalised. Sweeps written before the phase
    column existed get it from onset_s."""
    phase = rec[PHASE_KEY] if PHASE_KEY in rec else onset_phase(rec["onset_s"])
    phases, ip = bin_axis(np.asarray(phase, float), MAX_PHASE_BINS, 1.0)
    keys = ["control"] + [k for k in variant_keys if k in rec]
    combos = np.unique(np.stack([np.asarray(rec[k], float) for k in keys], 1), axis=0)
    rows = []
    for combo in combos:
        sel = np.all(np.stack([np.asarray(rec[k], float) == v for k, v in zip(keys, combo)], 1), 1)
        fell = np.bincount(ip[sel], rec["fell"][sel].astype(float), len(phases))
        count = np.bincount(ip[sel], minlength=len(phases)).astype(float)
        label = ("control on" if combo[0] else "control off") + "".join(
            f", {k}={v:g}" for k, v in zip(keys[1:], combo[1:]))
        with np.errstate(invalid="ignore"):
            rows.append((label, np.where(count > 0, fell / np.maximum(count, 1), np.nan), count))
    return dict(phases=phases, rows=rows)


def polar_mesh(azs, js):
    """Cell edges for pcolormesh on a polar axis (azimuth wraps around)."""
    a = np.radians(azs)
    da = np.diff(np.append(a, a[0] + 2 * np.pi)) if len(a) > 1 else np.array([2 * np.pi])
    a_edges = np.append(a - da / 2, a[-1] + da[-1] / 2)
    dj = np.diff(js) if len(js) > 1 else np.array([max(js[0], 0.1)])
    j_edges = np.concatenate([[max(js[0] - dj[0] / 2, 0.0)], js[:-1] + dj / 2,
                              [js[-1] + dj[-1] / 2]])
    return np.meshgrid(a_edges, j_edges, indexing="ij")
