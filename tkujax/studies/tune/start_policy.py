"""`tune.start_policy`: a tune that starts exactly at a policy file's scheduled controller.

    [tune]
    policy = "sectors8"
    start_policy = "recommended"    # or a policy file's path (relative to the current directory)

Without it a search starts at the spec's [controller] values with every schedule correction 0
(`PolicyReparam.latent_of`). With it the start is the file's controller (every field: the
file is the whole start, so the spec may not also give [controller]) and the file's schedule:
the scalar latents of the file's controller, the scheduled fields' latents the file's own
z_base, then the file's sector table or MLP weights in the layout of `PolicyReparam.schedule`.
So `PolicyReparam.schedule(z0)` is the file's schedule bit for bit, and `params_np(base, z0)`
its controller to float32 rounding (for the recommended policy: equal in float32 but for one
field, 1 ulp apart): the first candidate a search evaluates is the policy that
`tkujax sweep --params FILE` runs.

The file's layout must be the spec's: its kind and width those of tune.policy (and of every
policy of a [study]), its fields tune.schedule in order, its ranges (lo, hi, log) those of
tune.ranges for those fields, and its sharpness tune.sharpness. Anything else is a SpecError
naming tune.start_policy and the first difference: the same numbers under another layout are
another controller.
"""

from __future__ import annotations

import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.dialects.validation import SpecError

KEY = "tune.start_policy"


def policy_start(value, controller: dict):
    """(ControllerParams, Schedule or None) the tune starts from: the policy file `value`
    ("recommended": the shipped recommended policy) or, for None, the paper's values with
    [controller] applied and no schedule."""
    from tkujax.control.params_files import controller_params_from, load_policy_json

    if value is None:
        return controller_params_from(ControllerParams.paper(), controller).validate(), None

    if not isinstance(value, str) or not value:
        raise SpecError(f"{KEY}: expected a policy file's path or 'recommended', got {value!r}")
    if controller:
        raise SpecError(f"{KEY}: the policy file gives the whole start; remove [controller] "
                        f"({sorted(controller)}) or {KEY}")
    try:
        params, schedule = load_policy_json(value)
    except (OSError, ValueError) as err:
        raise SpecError(f"{KEY}: {err}") from None
    if schedule is None:
        raise SpecError(f"{KEY}: {value} holds no schedule (a plain parameter file): give "
                        "its values in [controller] instead")
    return params.validate(), schedule


def check_layout(reparam, schedule, policy_key: str) -> None:
    """SpecError naming the first difference between the policy file's schedule and the
    spec's layout `reparam` (a PolicyReparam of `policy_key`)."""
    def bad(what, theirs, ours):
        raise SpecError(f"{KEY}: the policy file's {what} is {theirs!r}, {policy_key} and "
                        f"tune.schedule / tune.ranges / tune.sharpness give {ours!r}: "
                        "the file's numbers mean another controller under this layout")

    if schedule.kind != reparam.kind:
        bad("kind", schedule.kind, reparam.kind)
    if tuple(schedule.fields) != tuple(reparam.schedule_fields):
        bad("fields", tuple(schedule.fields), tuple(reparam.schedule_fields))
    idx = [reparam.fields.index(f) for f in reparam.schedule_fields]
    for what, theirs, ours in (("lo", schedule.lo, [reparam.lo[i] for i in idx]),
                               ("hi", schedule.hi, [reparam.hi[i] for i in idx])):
        if not np.allclose(np.asarray(theirs, float), np.asarray(ours, float), rtol=1e-9,
                           atol=1e-12):
            bad(what, [float(x) for x in theirs], [float(x) for x in ours])
    if [bool(x) for x in schedule.log] != [bool(reparam.log[i]) for i in idx]:
        bad("log", list(schedule.log), [bool(reparam.log[i]) for i in idx])
    if not np.isclose(schedule.sharpness, reparam.sharpness, rtol=1e-12):
        bad("sharpness", schedule.sharpness, reparam.sharpness)
    rest = schedule_latents(schedule)
    if rest.size != reparam.schedule_size:
        bad("size (width)", rest.size, reparam.schedule_size)


def check_start_policy(spec) -> None:
    """The policy file fits tune.policy and every policy of the spec's [study]."""
    if spec.start_schedule is None:
        return
    policies = [("tune.policy", spec.policy)] + [
        (f"study.policies[{i}]", p) for i, p in enumerate((spec.study or {}).get("policies", []))]
    for key, policy in policies:
        check_layout(spec.policy_reparam(policy), spec.start_schedule, f"{key} = {policy!r}")
    # The file's scheduled values are map(z_base): a file whose controller disagrees was not
    # written from one latent, and the tune (which reads the value from z) would not start there.
    rep = spec.policy_reparam()
    idx = [rep.fields.index(f) for f in rep.schedule_fields]
    ours = np.asarray(rep.latent_of(spec.base_params()), float)[idx]
    theirs = np.asarray(spec.start_schedule.z_base, float)
    if not np.allclose(ours, theirs, atol=1e-4):
        f = rep.schedule_fields[int(np.argmax(np.abs(ours - theirs)))]
        raise SpecError(f"{KEY}: the policy file's controller value of {f} is not its "
                        f"schedule's z_base mapped onto its range (latents {ours.tolist()} "
                        f"against z_base {theirs.tolist()})")


def start_record(spec) -> dict | None:
    """What a tune's outputs record of tune.start_policy: the value given, the file read and
    its sha256 (None without one)."""
    if spec.start_policy is None:
        return None
    import hashlib

    from tkujax.control.params_files import policy_file_path

    path = policy_file_path(spec.start_policy)
    return dict(value=spec.start_policy, resolved=str(path.resolve()),
                sha256=hashlib.sha256(path.read_bytes()).hexdigest())


def schedule_latents(schedule) -> np.ndarray:
    """The schedule's numbers after the scalars, in `PolicyReparam.schedule`'s layout: the
    sector table row by row, or w1, b1, w2, b2 of an MLP."""
    if schedule.kind == "sectors":
        parts = [schedule.table]
    else:
        parts = [schedule.w1, schedule.b1, schedule.w2, schedule.b2]
    return np.concatenate([np.asarray(p, float).ravel() for p in parts])


def start_latent(spec, reparam) -> np.ndarray:
    """The latent a search of `spec` starts from, in `reparam`'s layout: `latent_of` the
    starting ControllerParams, and with tune.start_policy the file's schedule."""
    base: ControllerParams = spec.base_params()
    z = np.asarray(reparam.latent_of(base), float)
    schedule = spec.start_schedule
    if schedule is None:
        return z
    idx = [reparam.fields.index(f) for f in reparam.schedule_fields]
    z[idx] = np.asarray(schedule.z_base, float)
    z[reparam.k:] = schedule_latents(schedule)
    return z
