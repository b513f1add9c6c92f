"""Resource estimate of the fixed-point twin on the paper's FPGA (Altera Cyclone III EP3C120).

The operations are counted from the code itself, not from a hand-written list: `count_ops`
traces `controller_step_fx` abstractly (`jax.eval_shape`, nothing runs) with the word
primitives of the datapath (qformat.mul / add / sub / neg / div_fraction and
cordic.sincos / atan2 / sqrt) wrapped by recorders, and each controller module's entry point
(kalman, capture point, CPG, IK) wrapped to label what it calls. Vectorised calls count once
per element: `sincos(stack([a, b]))` is two CORDIC runs, both legs of the IK are 2 x.

Architecture (stated, the basis of every number): one datapath per module, time-multiplexed:
  * one multiplier per module, sized for the module's widest product; a product of an a-bit
    and a b-bit word takes ceil(a/18) * ceil(b/18) embedded 18x18 multipliers (the Cyclone III
    block; W x W gives ceil(W/18)^2). CORDIC gain corrections (magnitude, sqrt) use it too;
  * one iterative CORDIC unit per module (rotation, vectoring and hyperbolic modes), sized for
    the widest x/y and z registers used there: one micro-rotation per clock, a ROM of
    `iterations` atan words, barrel shifters for the variable shifts;
  * one saturating adder (ALU) per module, and the Kalman module's restoring divider;
  * operations of a module execute one after another; the modules run in sequence
    (Kalman -> detection / capture point -> CPG -> IK) once per control period.
"fully parallel" multipliers are also given: every product its own multiplier (an upper
bound of a design that instead pipelines everything).

Clock cycles per operation (rules of this estimate):
  mul         3 (registered inputs, the block's product register, round + saturate), +1 when
              the product spans several 18x18 blocks (the partial-product adder)
  add/sub/neg 1
  div         frac_bits + 2 (load, one quotient bit per cycle, the rounding bit)
  CORDIC      iterations + 2 (pre-rotation / fold, the micro-rotations, output rounding);
              sqrt + 1 more (normalising shift); gain multiplies are counted as `mul`
Registers (flip-flop bits): the controller state (`FixedControllerState`'s words), the
coefficient registers, one register per operation result (no reuse: an upper bound), and each
CORDIC unit's x, y, z and iteration counter and the divider's remainder / quotient.
Logic elements (a rough rule, stated): 1 LE per adder bit (Cyclone III arithmetic mode) and
per 2:1 multiplexer bit of a barrel shifter (ceil(log2 iterations) levels), 2 LEs per bit of
each multiplier's round/saturate stage, plus one LE per register bit (no packing with logic:
an upper bound). ROMs: atan tables (and the hyperbolic shift sequence) as M9K words.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import math

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.fixed.coefficients import MODE_BITS, Coefficients, coef_format
from tkujax.control.fixed.config import FixedPointConfig

# The paper's chip (Table 1): Altera Cyclone III EP3C120 (device handbook figures).
EP3C120 = dict(logic_elements=119_088, multipliers_18x18=288, m9k_blocks=432, m9k_bits=9216)
CLOCK_HZ = 50e6
BLOCK = 18
MODULES = ("kalman", "detect", "capture_point", "cpg", "ik")
_ENTRY = {"accel_to_angle_fx": "kalman", "kalman_step_fx": "kalman",
          "step_length_fx": "capture_point", "band_gate_fx": "capture_point",
          "cpg_feet_fx": "cpg", "solve_legs_fx": "ik"}
_WORD_OPS = ("mul", "add", "sub", "neg", "div_fraction")
# The submodules (the package re-exports functions of the same names, so look them up by path).
_mod = lambda name: importlib.import_module(f"tkujax.control.fixed.{name}")   # noqa: E731
qformat, cordic, controller_fx = _mod("qformat"), _mod("cordic"), _mod("controller_fx")
_OP_MODULES = tuple(_mod(n) for n in ("kalman_fx", "capture_point_fx", "cpg_fx", "ik_fx",
                                      "controller_fx", "cordic"))


@dataclasses.dataclass(frozen=True)
class Op:
    """One recorded operation: `count` parallel elements of one call.

    kind: mul, add, div, cordic_rot, cordic_vec, cordic_sqrt. widths: mul (a, b, out); add
    (out,); div (den, out frac bits); cordic (x/y register, z register (0 for sqrt),
    iterations, out)."""

    module: str
    kind: str
    count: int
    widths: tuple[int, ...]


def mul_blocks(a_bits: int, b_bits: int) -> int:
    """18x18 blocks of an a x b product: ceil(a/18) * ceil(b/18)."""
    return math.ceil(a_bits / BLOCK) * math.ceil(b_bits / BLOCK)


def op_cycles(op: Op) -> int:
    """Clock cycles of one element of `op` (module doc's rules)."""
    if op.kind == "mul":
        return 3 + (mul_blocks(op.widths[0], op.widths[1]) > 1)
    if op.kind == "add":
        return 1
    if op.kind == "div":
        return op.widths[1] + 2
    n = op.widths[2]
    return n + 2 + (op.kind == "cordic_sqrt")


def _elements(*arrays) -> int:
    shapes = [jnp.shape(a) for a in arrays if a is not None]
    return int(np.prod(jnp.broadcast_shapes(*shapes))) if shapes else 1


class _Recorder:
    def __init__(self):
        self.ops: list[Op] = []
        self.module = "detect"      # controller_fx's own glue: detection and the latch
        self.depth = 0              # > 0 inside a CORDIC call: its internals are the unit's

    def log(self, kind, count, widths):
        if self.depth == 0 or kind == "mul":
            self.ops.append(Op(self.module, kind, count, tuple(int(w) for w in widths)))


def _wrap_word(rec: _Recorder, name: str, fn):
    if name == "mul":
        def mul(a, fa, b, fb, out, rounding):
            rec.log("mul", _elements(a, b), (fa.word_bits, fb.word_bits, out.word_bits))
            return fn(a, fa, b, fb, out, rounding)
        return mul
    if name == "div_fraction":
        def div_fraction(num, den, out, rounding):
            # den is a word of the numerator's format; its width is not an argument: the
            # divider's subtractor is sized for the widest register, the cov word (kalman).
            rec.log("div", _elements(num, den), (rec.div_width, out.frac_bits))
            return fn(num, den, out, rounding)
        return div_fraction

    def word(*args):
        fmt = args[-1]
        rec.log("add", _elements(*args[:-1]), (fmt.word_bits,))
        return fn(*args)
    return word


def _wrap_cordic(rec: _Recorder, name: str, fn):
    def run(*args, **kw):
        if name == "sincos":
            theta, fin, fout, spec = args
            fxy, fz = cordic.rotation_formats(fin, fout, spec.guard_bits)
            kind, count, widths = "cordic_rot", _elements(theta), (fxy.word_bits, fz.word_bits)
            out_bits = fout.word_bits
        elif name == "atan2":
            y, x, fin, fang, spec = args[:5]
            fxy, fz = cordic.vector_formats(fin, fang, spec.guard_bits)
            kind, count, widths = "cordic_vec", _elements(y, x), (fxy.word_bits, fz.word_bits)
            out_bits = fang.word_bits
        else:
            v, fin, fout, spec = args
            fi = cordic.sqrt_formats(fout, spec.guard_bits)
            kind, count, widths = "cordic_sqrt", _elements(v), (fi.word_bits, 0)
            out_bits = fout.word_bits
        rec.log(kind, count, widths + (spec.iterations, out_bits))
        rec.depth += 1
        try:
            return fn(*args, **kw)
        finally:
            rec.depth -= 1
    return run


def _wrap_entry(rec: _Recorder, name: str, fn):
    def run(*args, **kw):
        outer, rec.module = rec.module, _ENTRY[name]
        try:
            return fn(*args, **kw)
        finally:
            rec.module = outer
    return run


@contextlib.contextmanager
def _recording(rec: _Recorder):
    """Wrap the primitives where the datapath modules look them up; always restored."""
    saved = []

    def patch(mod, name, new):
        saved.append((mod, name, getattr(mod, name)))
        setattr(mod, name, new)

    try:
        for mod in _OP_MODULES:
            for name in _WORD_OPS:
                if hasattr(mod, name) and getattr(mod, name) is getattr(qformat, name):
                    patch(mod, name, _wrap_word(rec, name, getattr(qformat, name)))
        for name in ("sincos", "atan2", "sqrt"):
            patch(cordic, name, _wrap_cordic(rec, name, getattr(cordic, name)))
        for name in _ENTRY:
            patch(controller_fx, name, _wrap_entry(rec, name, getattr(controller_fx, name)))
        yield rec
    finally:
        for mod, name, old in reversed(saved):
            setattr(mod, name, old)


def count_ops(config: FixedPointConfig, params=None, fn=None) -> list[Op]:
    """The operations of one control period (`controller_step_fx`), or of `fn()` (a function
    of no arguments calling datapath code, e.g. one module, for tests; module "fn")."""
    from tkujax.control.controller import Sensors
    from tkujax.control.controller_params import ControllerParams

    params = ControllerParams.paper() if params is None else params
    config = dataclasses.replace(config, straight_through=False)
    rec = _Recorder()
    rec.div_width = config.cov.word_bits
    with _recording(rec):
        if fn is not None:
            rec.module = "fn"
            jax.eval_shape(fn)
        else:
            state = controller_fx.controller_init_fx(params, config)
            sensors = Sensors(jnp.zeros(3, jnp.float32), jnp.zeros(3, jnp.float32))
            jax.eval_shape(lambda s, x: controller_fx.controller_step_fx(s, x, params, 1.0,
                                                                         config), state, sensors)
    return rec.ops


def state_register_bits(config: FixedPointConfig) -> dict[str, int]:
    """Bits of each word of `FixedControllerState` (the float views and gradient carriers are
    not hardware). A new int field without an entry here raises (tests keep it complete)."""
    c = config
    words = dict(phi=2 * c.state.word_bits, p=2 * c.cov.word_bits, tick=32, step_start_tick=32,
                 stepping=1, x_sup=c.length.word_bits, y_sup=c.length.word_bits,
                 phi_at_detect=c.state.word_bits,
                 delay=(c.latency_ticks + 1) * 12 * c.angle.word_bits)
    floats = {"x_sup_m", "y_sup_m", "step_weight", "shadow", "delay_grad"}
    fields = {f.name for f in dataclasses.fields(controller_fx.FixedControllerState)}
    missing = fields - set(words) - floats
    if missing:
        raise ValueError(f"state_register_bits: no width for FixedControllerState field(s) "
                         f"{sorted(missing)}")
    return words


def coefficient_register_bits(config: FixedPointConfig) -> int:
    return sum(1 if f.name in MODE_BITS else coef_format(f.name, config).word_bits
               for f in dataclasses.fields(Coefficients))


def module_resources(ops: list[Op], module: str) -> dict:
    """One module's datapath under the stated architecture."""
    mine = [o for o in ops if o.module == module]
    muls = [o for o in mine if o.kind == "mul"]
    cords = [o for o in mine if o.kind.startswith("cordic")]
    divs = [o for o in mine if o.kind == "div"]
    adds = [o for o in mine if o.kind == "add"]
    blocks = max((mul_blocks(*o.widths[:2]) for o in muls), default=0)
    parallel = sum(o.count * mul_blocks(*o.widths[:2]) for o in muls)
    n_iter = max((o.widths[2] for o in cords), default=0)
    w_xy = max((o.widths[0] for o in cords), default=0)
    w_z = max((o.widths[1] for o in cords), default=0)
    has_atan = any(o.kind != "cordic_sqrt" for o in cords)
    has_hyp = any(o.kind == "cordic_sqrt" for o in cords)
    counter = math.ceil(math.log2(n_iter + 1)) if n_iter else 0
    rom_words = (n_iter if has_atan else 0) + (n_iter if has_hyp else 0)
    rom_bits = (n_iter * w_z if has_atan else 0) + (n_iter * counter if has_hyp else 0)
    cycles = sum(o.count * op_cycles(o) for o in mine)
    # Registers: every result (upper bound), the CORDIC unit, the divider.
    result_bits = sum(o.count * (o.widths[2] if o.kind == "mul" else o.widths[0]
                                 if o.kind == "add" else o.widths[1] + 2 if o.kind == "div"
                                 else o.widths[3]) for o in mine)
    cordic_regs = (2 * w_xy + w_z + counter) if cords else 0
    div_regs = sum(o.widths[0] + o.widths[1] + 1 for o in divs[:1])
    alu = max((o.widths[0] for o in adds), default=0)
    mul_out = max((o.widths[2] for o in muls), default=0)
    shifter_levels = math.ceil(math.log2(n_iter)) if n_iter > 1 else 0
    logic = (alu + 2 * mul_out + (2 * w_xy + w_z + 2 * w_xy * shifter_levels if cords else 0)
             + sum(2 * o.widths[0] for o in divs[:1]))
    registers = result_bits + cordic_regs + div_regs
    return dict(
        module=module, multiplies=sum(o.count for o in muls),
        widest_product=(max((o.widths[:2] for o in muls), key=lambda w: mul_blocks(*w))
                        if muls else None),
        multipliers_18x18=blocks, multipliers_18x18_parallel=parallel,
        cordic_runs=sum(o.count for o in cords),
        cordic_runs_by_mode={k: sum(o.count for o in cords if o.kind == k)
                             for k in ("cordic_rot", "cordic_vec", "cordic_sqrt")},
        cordic_iterations=n_iter, cordic_stages_iterative=1 if cords else 0,
        cordic_stages_unrolled=sum(o.count * o.widths[2] for o in cords),
        cordic_xy_bits=w_xy, cordic_z_bits=w_z, divides=sum(o.count for o in divs),
        adds=sum(o.count for o in adds), rom_words=rom_words, rom_bits=rom_bits,
        m9k_blocks=math.ceil(rom_bits / EP3C120["m9k_bits"]) if rom_bits else 0,
        register_bits=registers, logic_elements=logic + registers, latency_cycles=cycles)


def resources(config: FixedPointConfig = FixedPointConfig(), params=None,
              clock_hz: float = CLOCK_HZ, control_period_s: float = 0.030) -> dict:
    """The estimate: per module, totals (state and coefficient registers included), the chip's
    capacity and the latency against the control period."""
    ops = count_ops(config, params)
    mods = [module_resources(ops, m) for m in MODULES]
    state = state_register_bits(config)
    coef = coefficient_register_bits(config)
    total = {k: sum(m[k] for m in mods) for k in
             ("multiplies", "multipliers_18x18", "multipliers_18x18_parallel", "cordic_runs",
              "cordic_stages_unrolled", "divides", "adds", "rom_words", "rom_bits", "m9k_blocks",
              "register_bits", "logic_elements", "latency_cycles")}
    regs = sum(state.values()) + coef
    total["register_bits"] += regs
    total["logic_elements"] += regs
    cycles = total["latency_cycles"]
    period_cycles = int(round(control_period_s * clock_hz))
    chip = EP3C120
    return dict(
        config=dataclasses.asdict(config), architecture="one time-multiplexed datapath per "
        "module (multiplier, iterative CORDIC, ALU; Kalman divider); modules in sequence",
        clock_hz=clock_hz, control_period_s=control_period_s, period_cycles=period_cycles,
        modules=mods, state_register_bits=state, coefficient_register_bits=coef, total=total,
        latency_s=cycles / clock_hz, latency_fraction_of_period=cycles / period_cycles,
        chip=dict(name="Altera Cyclone III EP3C120", **chip),
        utilisation=dict(
            multipliers=total["multipliers_18x18"] / chip["multipliers_18x18"],
            multipliers_parallel=total["multipliers_18x18_parallel"] / chip["multipliers_18x18"],
            logic_elements=total["logic_elements"] / chip["logic_elements"],
            m9k=total["m9k_blocks"] / chip["m9k_blocks"]),
        ops=[dataclasses.asdict(o) for o in ops])


def resources_markdown(res: dict) -> str:
    """The table (one row per module, a total row) and the chip comparison."""
    c = res["config"]
    fmt = lambda g: f"Q{c[g]['int_bits']}.{c[g]['frac_bits']}"   # noqa: E731
    t, u = res["total"], res["utilisation"]
    L = ["# EP3C120 resource estimate of the fixed-point controller twin", "",
         f"Config: angle {fmt('angle')}, rate {fmt('rate')}, length {fmt('length')} "
         f"(IK +{c['ik_guard_bits']} bits), accel {fmt('accel')}, unit {fmt('unit')}, "
         f"state {fmt('state')}, cov {fmt('cov')}, coefficients {c['coef_bits']} bits, "
         f"{c['cordic_iterations']} CORDIC iterations + {c['cordic_guard_bits']} guard bits, "
         f"latency {c['latency_ticks']} ticks.", "",
         f"Architecture: {res['architecture']}; clock {res['clock_hz'] / 1e6:g} MHz "
         f"({res['period_cycles']:,} cycles per {1e3 * res['control_period_s']:g} ms period). "
         "Operations counted from `controller_step_fx` by `tkujax.control.fixed.resources` "
         "(rules in its docstring). Estimates, not a synthesis result.", "",
         "| module | multiplies | 18x18 blocks (shared) | 18x18 (fully parallel) | CORDIC runs "
         "(rot/vec/sqrt) | CORDIC iterations | unrolled CORDIC stages | divides | adds | "
         "ROM words (M9K) | register bits | LEs (rough) | latency (cycles) |",
         "|---|" + "---|" * 12]
    for m in res["modules"]:
        if not (m["multiplies"] or m["cordic_runs"] or m["adds"] or m["divides"]):
            continue
        modes = m["cordic_runs_by_mode"]
        L.append(f"| {m['module']} | {m['multiplies']} | {m['multipliers_18x18']} | "
                 f"{m['multipliers_18x18_parallel']} | {m['cordic_runs']} "
                 f"({modes['cordic_rot']}/{modes['cordic_vec']}/{modes['cordic_sqrt']}) | "
                 f"{m['cordic_iterations']} | {m['cordic_stages_unrolled']} | {m['divides']} | "
                 f"{m['adds']} | {m['rom_words']} ({m['m9k_blocks']}) | {m['register_bits']:,} | "
                 f"{m['logic_elements']:,} | {m['latency_cycles']:,} |")
    regs = sum(res["state_register_bits"].values())
    L.append(f"| state + coefficient registers | | | | | | | | | | "
             f"{regs + res['coefficient_register_bits']:,} | "
             f"{regs + res['coefficient_register_bits']:,} | |")
    L.append(f"| **total** | {t['multiplies']} | {t['multipliers_18x18']} | "
             f"{t['multipliers_18x18_parallel']} | {t['cordic_runs']} | | "
             f"{t['cordic_stages_unrolled']} | {t['divides']} | {t['adds']} | "
             f"{t['rom_words']} ({t['m9k_blocks']}) | {t['register_bits']:,} | "
             f"{t['logic_elements']:,} | {t['latency_cycles']:,} |")
    ch = res["chip"]
    L += ["", f"Against the {ch['name']} ({ch['logic_elements']:,} LEs, "
          f"{ch['multipliers_18x18']} embedded 18x18 multipliers, {ch['m9k_blocks']} M9K "
          f"blocks of 9 Kbit):", "",
          f"- multipliers: {t['multipliers_18x18']} of {ch['multipliers_18x18']} "
          f"({100 * u['multipliers']:.1f} %) shared; {t['multipliers_18x18_parallel']} "
          f"({100 * u['multipliers_parallel']:.1f} %) if every product had its own",
          f"- logic elements (rough upper bound): {t['logic_elements']:,} "
          f"({100 * u['logic_elements']:.1f} %)",
          f"- M9K blocks: {t['m9k_blocks']} ({100 * u['m9k']:.1f} %)",
          f"- latency: {t['latency_cycles']:,} cycles = {1e6 * res['latency_s']:.1f} us at "
          f"{res['clock_hz'] / 1e6:g} MHz, {100 * res['latency_fraction_of_period']:.2f} % of "
          f"the {1e3 * res['control_period_s']:g} ms period", ""]
    return "\n".join(L)
