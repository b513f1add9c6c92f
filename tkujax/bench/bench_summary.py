"""The bench's readable summary: the Markdown beside its JSON."""

from __future__ import annotations


def summary_markdown(r: dict) -> str:
    lines = [f"# tkujax bench on {r['device_kind']} ({r['n_devices']} device(s))", "",
             f"Mode: {r.get('mode', 'default')}. Versions: {r['versions']}. Median of "
             f"{r['repeats']} runs; closed loop = {r['duration_s']} s pushes with controller, "
             f"sensors and metrics.", ""]
    if r["raw"] or r["closed_loop"]:
        lines += ["| batch | substep unroll | raw MJX steps/s (a) | closed-loop steps/s (b) | "
                  "pushes/s | b/a |", "|---|---|---|---|---|---|"]
        raw = {a["batch"]: a for a in r["raw"]}
        for b in r["closed_loop"]:
            a = raw.get(b["batch"])
            u = b.get("unroll_substeps", 1)
            lines.append(f"| {b['batch']} | {u} | {a['physics_steps_per_s']:.3g} | " if a else
                         f"| {b['batch']} | {u} | - | ")
            lines[-1] += (f"{b['physics_steps_per_s']:.3g} | {b['pushes_per_s']:.3g} | " +
                          (f"{b['physics_steps_per_s'] / a['physics_steps_per_s']:.2f} |" if a
                           else "- |"))
        for a in r["raw"]:
            if all(b["batch"] != a["batch"] for b in r["closed_loop"]):
                lines.append(f"| {a['batch']} | - | {a['physics_steps_per_s']:.3g} | - | - | - |")
    c = r.get("cpu_peer")
    if c and r["closed_loop"]:
        best = max(r["closed_loop"], key=lambda x: x["physics_steps_per_s"])
        lines += ["", f"CPU peer (MuJoCo C, batch {c['batch']}): {c['physics_steps_per_s']:.3g} "
                  f"steps/s, {c['pushes_per_s']:.3g} pushes/s; b/c = "
                  f"{best['physics_steps_per_s'] / c['physics_steps_per_s']:.1f}x"]
    elif c:
        lines += ["", f"CPU peer (MuJoCo C, batch {c['batch']}): {c['physics_steps_per_s']:.3g} "
                  f"steps/s, {c['pushes_per_s']:.3g} pushes/s"]
    g = r.get("gradient_step")
    if g:
        lines += ["", f"Gradient step (reverse mode through the closed loop, batch {g['batch']} x "
                  f"{g['duration_s']} s, {g['n_params']} parameters, remat {g['remat']}, float64 "
                  f"{g['float64']}): {g['seconds']:.2f} s per step = {g['pushes_per_s']:.3g} "
                  f"pushes/s, first call (compile) {g['first_call_s']:.0f} s"
                  + (" (read from the persistent cache: not a cold compile)"
                     if g.get("first_call_cache_hits") else "") + ", peak device "
                  "memory of the process (earlier stages included; run --stages "
                  "gradient_step alone for the step's own) "
                  + (f"{g['peak_device_bytes'] / 2**30:.2f} GiB" if g['peak_device_bytes']
                     else "n/a") + f", gradient finite: {g['grad_finite']}."]
    md = r.get("multi_device")
    if md:
        base = md[0]["pushes_per_s"]
        lines += ["", "| devices | batch | pushes/s | speed-up |", "|---|---|---|---|"]
        lines += [f"| {m['n_devices']} | {m['batch']} | {m['pushes_per_s']:.3g} | "
                  f"{m['pushes_per_s'] / base:.2f}x |" for m in md]
    gcs = r.get("gradient_compile") or []
    if gcs:
        lines += ["", "Compile of the tuning gradient (cold: empty persistent cache; includes "
                  "tracing and lowering):", "",
                  "| batch | variant | lower s | cold s | cached s | HLO chars | step s |",
                  "|---|---|---|---|---|---|---|"]
        for gc in gcs:
            v = gc.get("variant", gc.get("compiler_options")) or "tuner defaults"
            if "skipped" in gc:
                lines.append(f"| - | {v} | skipped: {gc['skipped']} | | | | |")
                continue
            lines.append(f"| {gc['batch']} | {v} | {gc.get('lower_s', '-')} | "
                         f"{gc['cold_s']:.1f} | {gc.get('cached_s', '-')} | "
                         f"{gc.get('hlo_chars', '-')} | {gc.get('step_s', '-')} |")
    for comp in r.get("compile_variants") or ([r["compile"]] if r.get("compile") else []):
        lines += ["", f"Compile of the closed loop (batch {comp.get('batch', '-')}, substep "
                  f"unroll {comp.get('unroll_substeps', 1)}): cold {comp['cold_s']:.1f} s, "
                  f"from the persistent cache {comp['cached_s']:.1f} s."]
    for p in r.get("profile") or []:
        lines += [""] + profile_markdown(p)
    if r.get("stages"):
        lines += ["", "| stage | status | wall s |", "|---|---|---|"]
        lines += [f"| {s['name']} | {s['status']}"
                  + (f" ({s['error'][:120]})" if s.get("error") else "")
                  + f" | {s.get('wall_s', '-')} |" for s in r["stages"]]
        lines += ["", f"Total wall time: {r.get('total_wall_s', 0):.1f} s"
                  + (f" over {r['runs']} runs (resumed)" if r.get("runs", 1) > 1 else "")
                  + ("" if r.get("complete") else " (incomplete: the run was cut short or is "
                     "still going)") + "."]
    return "\n".join(lines) + "\n"


def profile_markdown(p: dict) -> list[str]:
    """Markdown lines of one batch's profile (ablation table, then the controller's parts)."""
    if "n_ticks" not in p:
        return []                     # started, nothing measured yet
    lines = [f"### Closed-loop profile at batch {p['batch']} ({p['n_ticks']} ticks of "
             f"{p['substeps']} substeps, median of {p['repeats']})", "",
             "| variant | ms per tick | cost of the replaced part, ms per tick | share of full |",
             "|---|---|---|---|"]
    for r in p["rows"]:
        lines.append(f"| {r['variant']} | {r['ms_per_tick']:.3f} | {r['cost_ms_per_tick']:+.3f} "
                     f"| {100 * r['share_of_full']:+.1f} % |")
    if p.get("controller_parts") and p["rows"]:
        full = p["rows"][0]["ms_per_tick"]      # the full loop's row comes first
        lines += ["", "| controller part (alone) | ms per tick | share of full loop |",
                  "|---|---|---|"]
        lines += [f"| {c['part']} | {c['ms_per_tick']:.4f} | "
                  f"{100 * c['ms_per_tick'] / full:.1f} % |" for c in p["controller_parts"]]
    if p.get("trace_dir"):
        lines += ["", f"jax.profiler trace of the full loop: `{p['trace_dir']}`."]
    ts = p.get("trace_scopes") or {}
    if ts.get("scopes"):
        lines += ["", f"Trace events by named scope ({ts['events_matched']} events matched to "
                  f"the program's instructions, {ts['events_unmatched']} not):", "",
                  "| scope | ms per tick | share of matched |", "|---|---|---|"]
        lines += [f"| {k} | {v['ms_per_tick']:.4f} | "
                  + (f"{100 * v['share']:.1f} %" if v["share"] is not None else "-") + " |"
                  for k, v in ts["scopes"].items()]
    elif ts.get("error"):
        lines += ["", f"Trace by scope: {ts['error']}"]
    return lines
