"""`tkujax converge`: numerical convergence of the fall outcomes in the timestep and the solver
(calibration in expectation).

The same pushes run under each physics setting of the spec (ModelParams.timestep_s,
solver_iterations, ls_iterations; everything else the default robot and the paper's controller),
and every setting's fall outcomes are compared push by push with the reference setting (by
default the finest: smallest timestep, then most iterations). Two sets of pushes:

  paper  the paper's 8 rows (`tkujax paper`'s balls, contact and controller) at `phases` hit
         phases over the 30 ms control period: 8 x phases pushes.
  wide   `pushes` random pushes per controller (off, and the paper's controller on): azimuth
         uniform over [0, 360) deg, impulse uniform over impulse_ns, hit phase uniform over the
         control period (onset 0.75 s + phase x 30 ms), 20 ms pulse at height_m. The same pushes
         for both controllers and every setting (seeded).

A setting may scale every impulse (impulse_scale, e.g. 1.001): run at the reference's physics it
measures the sensitivity floor, the agreement one can expect at all when the pushes themselves
move by that much, i.e. how many pushes lie that close to a fall boundary.

Agreement of a setting = the fraction of pushes whose fall outcome equals the reference's, per
set and controller, with a 95 % Wilson interval; pushes that diverged (tkujax.sim.metrics) in
either setting are counted apart and excluded. Also per setting: the paper rows' fall outcomes as
in the paper (of 8 x phases), and the step lengths' largest change against the reference.

Outputs (into --out): spec.json (the validated spec), outcomes_<setting>.npz per setting (a
rerun skips settings already there, so an interrupted study resumes; `--only` runs a subset),
agreement.json and agreement.md (written from all settings present).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from tkujax.dialects.validation import SpecError, in_range, read_toml, table

BACKENDS = ("mujoco", "mjx")
CONTROLS = ("off", "on")


@dataclasses.dataclass(frozen=True)
class Setting:
    name: str
    timestep_ms: float
    solver_iterations: int
    ls_iterations: int
    impulse_scale: float = 1.0   # != 1: every push's impulse scaled, a sensitivity floor (below)

    def model_params(self):
        from tkujax.model import ModelParams

        return dataclasses.replace(ModelParams(), timestep_s=1e-3 * self.timestep_ms,
                                   solver_iterations=self.solver_iterations,
                                   ls_iterations=self.ls_iterations).validate()


@dataclasses.dataclass(frozen=True)
class ConvergeSpec:
    name: str
    backend: str
    batch: int
    settings: tuple[Setting, ...]
    reference: str
    phases: int
    pushes: int
    impulse_ns: tuple[float, float]
    height_m: float
    duration_s: float
    seed: int

    def setting(self, name: str) -> Setting:
        return next(s for s in self.settings if s.name == name)


def _num(given: dict, key: str, where: str, lo: float, hi: float, default=None, integer=False):
    """given[key] (or default): a number (an integer) in [lo, hi], named where.key."""
    return in_range(f"{where}.{key}", given.get(key, default), lo, hi, integer)


def parse_spec(data: dict) -> ConvergeSpec:
    """Validate a spec dict (the TOML); SpecError names the key and its allowed range."""
    allowed = {"converge", "paper", "wide"}
    if set(data) - allowed:
        raise SpecError(f"unknown table(s) {sorted(set(data) - allowed)}; allowed: "
                        f"{sorted(allowed)}")
    c = data.get("converge", {})
    known = {"name", "backend", "batch", "reference", "setting"}
    table("converge", c, known)
    name = c.get("name", "converge")
    if not isinstance(name, str) or not name.replace("_", "").replace("-", "").isalnum():
        raise SpecError(f"converge.name must be letters, digits, - or _, got {name!r}")
    backend = c.get("backend", "mujoco")
    if backend not in BACKENDS:
        raise SpecError(f"converge.backend must be one of {BACKENDS}, got {backend!r}")
    batch = _num(c, "batch", "converge", 1, 1 << 20, 1024, integer=True)
    raw = c.get("setting")
    if not isinstance(raw, list) or len(raw) < 2:
        raise SpecError("[[converge.setting]] must be given at least twice (a reference and a "
                        "setting to compare)")
    settings = []
    for i, s in enumerate(raw):
        where = f"converge.setting[{i}]"
        extra = set(s) - {"name", "timestep_ms", "solver_iterations", "ls_iterations",
                          "impulse_scale"}
        if extra:
            raise SpecError(f"{where}: unknown key(s) {sorted(extra)}; allowed: name, "
                            "timestep_ms, solver_iterations, ls_iterations, impulse_scale")
        ts = _num(s, "timestep_ms", where, 0.5, 10.0)
        if abs(30.0 / ts - round(30.0 / ts)) > 1e-6:
            raise SpecError(f"{where}.timestep_ms must divide the 30 ms control period, "
                            f"got {ts!r}")
        it = _num(s, "solver_iterations", where, 1, 100, 1, integer=True)
        ls = _num(s, "ls_iterations", where, 1, 100, 4, integer=True)
        scale = _num(s, "impulse_scale", where, 0.5, 2.0, 1.0)
        nm = s.get("name", f"{ts:g}ms-newton{it}-ls{ls}" + (
            "" if scale == 1.0 else f"-imp{scale:g}"))
        if not isinstance(nm, str) or not nm.replace("_", "").replace("-", "").replace(
                ".", "").isalnum():
            raise SpecError(f"{where}.name must be letters, digits, '.', '-' or '_', "
                            f"got {nm!r}")
        settings.append(Setting(nm, float(ts), int(it), int(ls), float(scale)))
    names = [s.name for s in settings]
    if len(set(names)) != len(names):
        raise SpecError(f"converge.setting names must be distinct, got {names}")
    finest = min((s for s in settings if s.impulse_scale == 1.0),
                 key=lambda s: (s.timestep_ms, -s.solver_iterations, -s.ls_iterations),
                 default=settings[0]).name
    reference = c.get("reference", finest)
    if reference not in names:
        raise SpecError(f"converge.reference must be one of the setting names {names}, "
                        f"got {reference!r}")
    p = data.get("paper", {})
    table("paper", p, {"phases"})
    phases = _num(p, "phases", "paper", 0, 100, 15, integer=True)
    w = data.get("wide", {})
    wk = {"pushes", "impulse_ns", "height_m", "duration_s", "seed"}
    table("wide", w, wk)
    pushes = _num(w, "pushes", "wide", 0, 1 << 20, 512, integer=True)
    imp = w.get("impulse_ns", [0.2, 1.8])
    if (not isinstance(imp, list) or len(imp) != 2
            or not all(isinstance(v, (int, float)) and 0.0 < v <= 10.0 for v in imp)
            or imp[0] > imp[1]):
        raise SpecError(f"wide.impulse_ns must be [lo, hi] with 0 < lo <= hi <= 10 N s, "
                        f"got {imp!r}")
    from tkujax.sim.push import BallContact, DEFAULT_DURATION_S

    height = _num(w, "height_m", "wide", 0.25, 0.46, BallContact().height_m)
    dur = _num(w, "duration_s", "wide", 0.002, 0.5, DEFAULT_DURATION_S)
    seed = _num(w, "seed", "wide", 0, 2**31 - 1, 0, integer=True)
    if phases == 0 and pushes == 0:
        raise SpecError("paper.phases and wide.pushes are both 0: nothing to run")
    return ConvergeSpec(name, backend, int(batch), tuple(settings), reference, int(phases),
                        int(pushes), (float(imp[0]), float(imp[1])), float(height), float(dur),
                        int(seed))


def load_spec(path: str | Path) -> ConvergeSpec:
    return parse_spec(read_toml(path))


def spec_dict(spec: ConvergeSpec) -> dict:
    return dataclasses.asdict(spec)


def pushes_of(spec: ConvergeSpec):
    """(pushes stacked, enabled (n,), dict of labels): the paper rows (phase-major) then the wide
    set for control off, then the same wide set for control on."""
    from tkujax.sim import push as push_lib
    from tkujax.studies.paper import paper_cases

    contact = push_lib.BallContact()
    cases = paper_cases()
    plist, enabled, label = [], [], dict(set=[], control=[], phase=[], row=[])
    for k in range(spec.phases):
        onset = float(push_lib.onset_from_phase(push_lib.PAPER_ONSET_S, k / spec.phases))
        for i, (d, b, c) in enumerate(cases):
            plist.append(contact.push(b, d, onset_s=onset))
            enabled.append(1.0 if c == "on" else 0.0)
            label["set"].append("paper"), label["control"].append(c)
            label["phase"].append(k / spec.phases), label["row"].append(i)
    rng = np.random.default_rng(spec.seed)
    imp = rng.uniform(*spec.impulse_ns, spec.pushes)
    az = rng.uniform(0.0, 360.0, spec.pushes)
    phase = rng.uniform(0.0, 1.0, spec.pushes)
    for c in CONTROLS:
        for j in range(spec.pushes):
            onset = float(push_lib.onset_from_phase(push_lib.PAPER_ONSET_S, phase[j]))
            plist.append(push_lib.make_push(float(imp[j]), float(az[j]), height_m=spec.height_m,
                                            duration_s=spec.duration_s, onset_s=onset))
            enabled.append(1.0 if c == "on" else 0.0)
            label["set"].append("wide"), label["control"].append(c)
            label["phase"].append(float(phase[j])), label["row"].append(-1)
    return (push_lib.stack_pushes(plist), np.asarray(enabled, np.float32),
            {k: np.asarray(v) for k, v in label.items()})


def _simulate(spec: ConvergeSpec, setting: Setting, pushes, enabled) -> dict:
    """Outcomes (numpy dict) of every push under one setting, in batches of spec.batch (the last
    padded to the same shape, so MJX compiles once per setting)."""
    import jax

    from tkujax.control.controller_params import ControllerParams

    mp = setting.model_params()
    params = ControllerParams.paper(mp)
    if setting.impulse_scale != 1.0:
        pushes = dataclasses.replace(pushes, impulse_ns=np.asarray(pushes.impulse_ns)
                                     * np.float32(setting.impulse_scale))
    n = int(np.shape(pushes.impulse_ns)[0])
    keep = ("fell", "diverged", "recovery_time_s", "recovery_time_pitch_s", "step_length_m",
            "step_width_m", "peak_incl_deg")
    parts = {k: [] for k in keep}
    for a in range(0, n, spec.batch):
        idx = np.minimum(np.arange(a, a + spec.batch), n - 1)
        if n - a < spec.batch and spec.backend == "mujoco":
            idx = np.arange(a, n)                    # no compile to share: no padding
        chunk = jax.tree_util.tree_map(lambda v, idx=idx: np.asarray(v)[idx], pushes)
        if spec.backend == "mujoco":
            from tkujax.sim.rollout_mujoco import simulate_mujoco
            _, out = simulate_mujoco(chunk, enabled[idx], params, model_params=mp)
        else:
            from tkujax.sim.rollout_mjx import simulate
            _, out = simulate(chunk, enabled[idx], params, model_params=mp)
        m = min(spec.batch, n - a)
        for k in keep:
            parts[k].append(np.asarray(out[k])[:m])
    return {k: np.concatenate(v) for k, v in parts.items()}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion k / n."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def agreement(spec: ConvergeSpec, labels: dict, results: dict[str, dict]) -> dict:
    """Per setting present in `results`: agreement with the reference (see the module doc)."""
    from tkujax.studies.paper import PAPER_TABLE, paper_cases

    ref = results[spec.reference]
    cases = paper_cases()
    paper_fall = np.array([PAPER_TABLE[c][0] is None for c in cases])
    out = {}
    for s in spec.settings:
        if s.name not in results:
            continue
        r = results[s.name]
        entry = dict(timestep_ms=s.timestep_ms, solver_iterations=s.solver_iterations,
                     ls_iterations=s.ls_iterations, impulse_scale=s.impulse_scale,
                     wall_s=float(r.get("wall_s", math.nan)))
        for set_name in ("paper", "wide"):
            for c in CONTROLS:
                sel = (labels["set"] == set_name) & (labels["control"] == c)
                if not sel.any():
                    continue
                div = (r["diverged"] | ref["diverged"]) & sel
                ok = sel & ~div
                same = int(np.sum((r["fell"] == ref["fell"]) & ok))
                n = int(ok.sum())
                lo, hi = wilson(same, n)
                both_up = ok & ~r["fell"] & ~ref["fell"]
                dstep = np.abs(r["step_length_m"] - ref["step_length_m"])[both_up]
                entry[f"{set_name}_{c}"] = dict(
                    n=n, agree=same, fraction=same / n if n else math.nan, wilson95=[lo, hi],
                    diverged=int(div.sum()), fell=int(np.sum(r["fell"] & ok)),
                    fell_ref=int(np.sum(ref["fell"] & ok)),
                    max_step_change_cm=float(100 * dstep.max()) if dstep.size else 0.0)
        psel = labels["set"] == "paper"
        if psel.any():
            rows = labels["row"][psel]
            fell = r["fell"][psel]
            as_paper = fell == paper_fall[rows]
            entry["paper_as_paper"] = dict(
                n=int(psel.sum()), agree=int(as_paper.sum()),
                phase0=int(as_paper[labels["phase"][psel] == 0.0].sum()),
                per_row_fall_fraction={"/".join(cases[i]): float(fell[rows == i].mean())
                                       for i in range(len(cases))})
        out[s.name] = entry
    return out


def agreement_markdown(spec: ConvergeSpec, agr: dict, device: str) -> str:
    lines = [f"# Convergence: {spec.name}", "",
             f"Backend {spec.backend}, device {device}. Reference: **{spec.reference}**. "
             f"Paper rows: 8 x {spec.phases} phases; wide set: {spec.pushes} pushes per "
             f"controller (azimuth 0-360 deg, {spec.impulse_ns[0]:g}-{spec.impulse_ns[1]:g} N s, "
             f"phase uniform over the 30 ms period, height {spec.height_m:g} m, "
             f"{1000 * spec.duration_s:g} ms pulse, seed {spec.seed}).", "",
             "Fall outcomes equal to the reference's, fraction [95 % Wilson interval] (pushes "
             "that diverged in either setting left out, counted in 'div.'):", "",
             "| setting | dt (ms) | Newton it. | ls it. | impulse x | wide, control off | "
             "wide, control on | "
             "paper rows, off | paper rows, on | paper rows as the paper (phase 0 / all) | "
             "div. | max step change (cm, wide on) | wall (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def cell(e):
        if e is None:
            return "-"
        return (f"{e['fraction']:.4f} ({e['agree']}/{e['n']}) "
                f"[{e['wilson95'][0]:.3f}, {e['wilson95'][1]:.3f}]")

    for name, e in agr.items():
        pa = e.get("paper_as_paper")
        div = sum(e[k]["diverged"] for k in e if isinstance(e[k], dict) and "diverged" in e[k])
        pa_s = "-" if pa is None else f"{pa['phase0']}/8, {pa['agree']}/{pa['n']}"
        lines.append(
            f"| {name}{' (ref.)' if name == spec.reference else ''} | {e['timestep_ms']:g} | "
            f"{e['solver_iterations']} | {e['ls_iterations']} | {e['impulse_scale']:g} | "
            f"{cell(e.get('wide_off'))} | "
            f"{cell(e.get('wide_on'))} | {cell(e.get('paper_off'))} | {cell(e.get('paper_on'))}"
            f" | {pa_s} | {div} | "
            f"{e['wide_on']['max_step_change_cm'] if 'wide_on' in e else 0:.2f} | "
            f"{e['wall_s']:.0f} |")
    if any("paper_as_paper" in e for e in agr.values()):
        lines += ["", "Paper rows: fall fraction over the phases, per setting:", "",
                  "| row | " + " | ".join(agr) + " |", "|---|" + "---|" * len(agr)]
        rows = next(iter(agr.values()))["paper_as_paper"]["per_row_fall_fraction"]
        for row in rows:
            lines.append(f"| {row.replace('/', ' ')} | " + " | ".join(
                f"{e['paper_as_paper']['per_row_fall_fraction'][row]:.2f}" for e in agr.values())
                + " |")
    return "\n".join(lines) + "\n"


def run_converge(spec: ConvergeSpec, out: str | Path, only: tuple[str, ...] = (),
                 log=print, run: bool = True, reference: str | None = None) -> dict:
    """Run the settings missing from `out` (all, or those named in `only`; none when run is
    False), then write agreement.json / agreement.md from every setting present. reference: a
    setting name to compare against instead of the spec's (the report is then written as
    agreement_vs_<name>.json / .md, beside the spec's). Returns the agreement dict."""
    import jax

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = [s.name for s in spec.settings]
    bad = [o for o in only if o not in names]
    if bad:
        raise SpecError(f"--only: unknown setting(s) {bad}; allowed: {names}")
    if reference is not None and reference not in names:
        raise SpecError(f"--reference must be one of the setting names {names}, "
                        f"got {reference!r}")
    sd = spec_dict(spec)
    sp = out / "spec.json"
    new = json.loads(json.dumps(sd))
    if sp.exists():
        # Settings may be added or dropped; the pushes (and a kept setting) may not change.
        old = json.loads(sp.read_text())
        same = {k: v for k, v in old.items() if k not in ("settings", "reference", "batch")} \
            == {k: v for k, v in new.items() if k not in ("settings", "reference", "batch")}
        kept = {s["name"]: {"impulse_scale": 1.0, **s} for s in old["settings"]}
        same = same and all(kept.get(s["name"], s) == s for s in new["settings"])
        if not same:
            raise SpecError(f"{out} holds a convergence spec with other pushes or settings "
                            "(spec.json); use another --out or remove it")
    sp.write_text(json.dumps(new, indent=1))
    pushes, enabled, labels = pushes_of(spec)
    device = str(jax.devices()[0]) if spec.backend == "mjx" else "CPU (MuJoCo C)"
    for s in spec.settings:
        f = out / f"outcomes_{s.name}.npz"
        if not run or f.exists() or (only and s.name not in only):
            continue
        t0 = time.perf_counter()
        res = _simulate(spec, s, pushes, enabled)
        wall = time.perf_counter() - t0
        np.savez_compressed(f, wall_s=wall, device=device, **res)
        log(f"{s.name}: {len(enabled)} rollouts in {wall:.1f} s ({device})")
    results = {}
    for s in spec.settings:
        f = out / f"outcomes_{s.name}.npz"
        if f.exists():
            with np.load(f) as z:
                results[s.name] = {k: z[k] for k in z.files}
    stem = "agreement"
    if reference is not None and reference != spec.reference:
        spec = dataclasses.replace(spec, reference=reference)
        stem = f"agreement_vs_{reference}"
    if spec.reference not in results:
        log(f"reference {spec.reference} not run yet: no agreement written")
        return {}
    agr = agreement(spec, labels, results)
    devices = sorted({str(r["device"]) for r in results.values()})
    (out / f"{stem}.json").write_text(json.dumps(dict(devices=devices, settings=agr), indent=1))
    md = agreement_markdown(spec, agr, ", ".join(devices))
    (out / f"{stem}.md").write_text(md)
    log(md)
    return agr
