"""The [compare] and [study] tables of tune specs: which methods, seeds (and policies) run at
one wall-clock budget, and the search settings they share."""

from __future__ import annotations

from tkujax.dialects.sweep_spec import PUSH_FIELDS
from tkujax.studies.tune.parameterisations import parse_policy
from tkujax.studies.tune.searchers import METHODS
from tkujax.studies.tune.selection import SELECT_MODES
from tkujax.dialects.validation import SpecError, boolean, integer, number, table


def policy_name(key: str, value) -> str:
    try:
        parse_policy(value)
    except ValueError as e:
        raise SpecError(f"{key}: {e}") from None
    return value


COMPARE_FIELDS = {"methods", "seeds", "budget_s", "popsize", "sigma0", "zo_sigma", "groups",
                  "learning_rate", "temperature_deg", "push_clip", "ray_radius", "ray_ratio",
                  "eval_n"}


def methods_list(table: str, c: dict, default: list) -> list:
    methods = c.get("methods", default)
    if (not isinstance(methods, list) or not methods or any(m not in METHODS for m in methods)
            or len(set(methods)) != len(methods)):
        raise SpecError(f"{table}.methods: expected distinct names from {list(METHODS)}, "
                        f"got {methods!r}")
    return list(methods)


def search_settings(table: str, c: dict, batch: int, popsize: int, budget_s: float,
                     budget_min_s: float) -> dict:
    """The settings a [compare] or [study] table shares: groups, popsize and the methods'
    steps (defaults: popsize, budget_s; budget_s at least budget_min_s)."""
    groups = integer(f"{table}.groups", c.get("groups", 4), 1, 1024)
    if batch % groups:
        raise SpecError(f"{table}.groups: {groups} must divide tune.batch = {batch}")
    popsize = integer(f"{table}.popsize", c.get("popsize", popsize), 3, 4096)
    if popsize % 2 == 0:
        raise SpecError(f"{table}.popsize: expected an odd number (centre + antithetic pairs), "
                        f"got {popsize}")
    return dict(
        groups=groups, popsize=popsize,
        budget_s=number(f"{table}.budget_s", c.get("budget_s", budget_s), budget_min_s,
                         86400.0, "s"),
        sigma0=number(f"{table}.sigma0", c.get("sigma0", 0.5), 1e-3, 10.0, "(latent)"),
        zo_sigma=number(f"{table}.zo_sigma", c.get("zo_sigma", 0.3), 1e-3, 10.0, "(latent)"),
        learning_rate=number(f"{table}.learning_rate", c.get("learning_rate", 0.1), 1e-5,
                              10.0),
        temperature_deg=number(f"{table}.temperature_deg", c.get("temperature_deg", 0.5),
                                1e-3, 30.0, "deg"),
        # gradient, hybrid: clip each push's gradient at push_clip x the batch's median
        # per-push norm before the mean (0: the plain mean; search.first_order_grads)
        push_clip=number(f"{table}.push_clip", c.get("push_clip", 0.0), 0.0, 1e6,
                          "(x median norm)"),
        # linesearch: the longest step of its first ray (searchers.LineSearcher)
        ray_radius=number(f"{table}.ray_radius", c.get("ray_radius", 2.0), 1e-3, 100.0,
                           "(latent)"),
        ray_ratio=number(f"{table}.ray_ratio", c.get("ray_ratio", 0.5), 0.05, 0.95,
                          "(each radius over the previous)"),
        eval_n=integer(f"{table}.eval_n", c.get("eval_n", 4 * batch), 1, 10_000_000))


def parse_compare(raw, batch: int) -> dict:
    c = table("compare", raw, COMPARE_FIELDS)
    methods = methods_list("compare", c, ["cma", "hybrid", "es"])
    seeds = c.get("seeds", [0, 1, 2])
    if not isinstance(seeds, list) or not seeds or any(
            isinstance(x, bool) or not isinstance(x, int) or x < 0 for x in seeds):
        raise SpecError(f"compare.seeds: expected a list of non-negative integers, got {seeds!r}")
    return dict(methods=methods, seeds=list(seeds),
                **search_settings("compare", c, batch, 9, 60.0, 1.0))


STUDY_FIELDS = {"policies", "methods", "seeds", "budget_s", "popsize", "sigma0", "zo_sigma",
                "push_clip", "ray_radius", "ray_ratio", "groups", "learning_rate",
                "temperature_deg", "eval_n",
                "above_impulse_ns", "sep_cma_from", "margin_s", "compile_s", "seeds_side_by_side",
                "guided_steps", "budget_includes_compile", "heldout_checkpoints", "select",
                "select_n", "select_every_s", "fresh_batches"}


def parse_study(raw, batch: int) -> dict:
    """[study]: every policy x method x seed at one budget (tkujax.studies.tune.dimension_study)."""
    c = table("study", raw, STUDY_FIELDS)
    policies = c.get("policies", ["scalars", "sectors4", "sectors8", "mlp"])
    if not isinstance(policies, list) or not policies or len(set(policies)) != len(policies):
        raise SpecError(f"study.policies: expected a list of distinct policy names, "
                        f"got {policies!r}")
    for i, p in enumerate(policies):
        policy_name(f"study.policies[{i}]", p)
    methods = methods_list("study", c, list(METHODS))
    seeds = c.get("seeds", [0, 1, 2])
    if not isinstance(seeds, list) or not seeds or len(set(seeds)) != len(seeds) or any(
            isinstance(x, bool) or not isinstance(x, int) or x < 0 for x in seeds):
        raise SpecError(f"study.seeds: expected a list of distinct non-negative integers, "
                        f"got {seeds!r}")
    above = c.get("above_impulse_ns")
    if above is not None:
        lo, hi, _, unit = PUSH_FIELDS["impulse_ns"]
        if not (isinstance(above, list) and len(above) == 2):
            raise SpecError(f"study.above_impulse_ns: expected [lo, hi] in N·s, got {above!r}")
        a = number("study.above_impulse_ns[0]", above[0], lo, hi, unit)
        b = number("study.above_impulse_ns[1]", above[1], lo, hi, unit)
        if not a < b:
            raise SpecError(f"study.above_impulse_ns: lower bound {a} must be below {b}")
        above = (a, b)
    settings = search_settings("study", c, batch, 15, 120.0, 0.1)
    return dict(
        policies=list(policies), methods=methods, seeds=list(seeds), above_impulse_ns=above,
        **settings,
        sep_cma_from=integer("study.sep_cma_from", c.get("sep_cma_from", 64), 1, 1_000_000),
        margin_s=number("study.margin_s", c.get("margin_s", 60.0), 0.0, 86400.0, "s"),
        compile_s=number("study.compile_s", c.get("compile_s", 180.0), 0.0, 86400.0, "s"),
        # The seeds of one (policy, method) in lockstep, sharing every compiled call
        # (tkujax.studies.tune.lockstep); false: one run after another, each alone.
        seeds_side_by_side=boolean("study.seeds_side_by_side",
                                 c.get("seeds_side_by_side", False)),
        # guided_sepcma / guided_cma: the step multipliers a of the injected candidates
        # m - sigma sqrt(k) a g/|g| (searchers.GuidedCMASearcher), fewer than popsize
        # (default 0.5, 1, 2, as many as popsize - 1 allows)
        guided_steps=guided_steps(c.get("guided_steps", [0.5, 1.0, 2.0][:settings["popsize"] - 1]),
                                  settings["popsize"]),
        # Each run's budget_s counts its own compiles (tkujax.studies.tune.budget_clock)
        budget_includes_compile=boolean("study.budget_includes_compile",
                                      c.get("budget_includes_compile", False)),
        # With compile included: held-out fall of the best-so-far at i/N of the budget
        heldout_checkpoints=integer("study.heldout_checkpoints",
                                    c.get("heldout_checkpoints", 4), 1, 20),
        **selection_settings(c, batch))


def selection_settings(c: dict, batch: int) -> dict:
    """study.select ("training": the lowest training loss; "validation": the lowest hard fall
    rate on select_n validation pushes, looked at every select_every_s seconds) and
    study.fresh_batches (a fresh training batch per iteration; seeds side by side only):
    tkujax.studies.tune.selection."""
    select = c.get("select", "training")
    if select not in SELECT_MODES:
        raise SpecError(f"study.select: expected one of {list(SELECT_MODES)}, got {select!r}")
    fresh = boolean("study.fresh_batches", c.get("fresh_batches", False))
    if fresh and not c.get("seeds_side_by_side", False):
        raise SpecError("study.fresh_batches: needs study.seeds_side_by_side = true")
    return dict(select=select, fresh_batches=fresh,
                select_n=integer("study.select_n", c.get("select_n", 2 * batch), 1, 1_000_000),
                select_every_s=number("study.select_every_s", c.get("select_every_s", 10.0),
                                      0.1, 86400.0, "s"))


def guided_steps(v, popsize: int) -> tuple[float, ...]:
    if not isinstance(v, list) or not 1 <= len(v) < popsize:
        raise SpecError(f"study.guided_steps: expected 1..{popsize - 1} step multipliers "
                        f"(fewer than study.popsize), got {v!r}")
    return tuple(number(f"study.guided_steps[{i}]", a, 1e-3, 100.0, "(x sigma sqrt(k))")
                 for i, a in enumerate(v))
