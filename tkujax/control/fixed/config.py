"""FixedPointConfig: word lengths, CORDIC, rounding and latency of the FPGA controller twin.

Defaults model an 18-bit datapath (the paper's Cyclone III EP3C120 has 18x18 multipliers) with
a 24-bit Kalman accumulator, 16 CORDIC iterations and 2 guard bits:

  group   unit     default   range / resolution        why
  angle   rad      Q2.15     +-4 rad, 3.1e-5 rad        +-pi for atan2/acos; LSB << servo 1.5e-3
  rate    rad/s    Q5.12     +-32 rad/s, 2.4e-4         gyro full scale ~ +-1800 deg/s
  length  m        Q0.17     +-1 m, 7.6e-6 m            leg 0.22 m, steps < 0.2 m
  accel   g        Q3.14     +-8 g, 6.1e-5 g            MEMS +-8 g range (input given in m/s^2)
  unit    -        Q2.15     +-4, 3.1e-5                sin, cos, ratios, Kalman gain
  state   rad      Q2.21     +-4 rad, 4.8e-7 rad        accumulates gyro*dt ~ 1e-5 per tick
  cov     rad^2    Q-3.20    +-0.125, 9.5e-7            P ~ 5e-4 .. 3e-3
  coef    -        18 bits   binary point per coefficient (coefficients.py)
  IK      m        Q0.21     length + ik_guard_bits: the IK's internal lengths

Limits: every group's word 1 + int_bits + frac_bits is <= 26 bits and guard bits <= 3, so the
widest CORDIC register (word + 2 headroom + 3 guard bits) still fits the 31-bit limit of the
int32 datapath (qformat.py).
"""

from __future__ import annotations

import dataclasses
import math

from tkujax.control.fixed.qformat import ROUNDING_MODES, QFormat

MAX_GROUP_WORD_BITS = 26

# Allowed integer bits per signal group: angles need +-pi (and at most +-8 for the one-step
# angle wrap of the CORDIC); the others are physical ranges wide enough for any push.
_INT_BITS = {"angle": (2, 3), "rate": (0, 8), "length": (0, 4), "accel": (1, 6),
             "unit": (1, 3), "state": (2, 3), "cov": (-12, 4)}
GROUP_INT_BITS = _INT_BITS   # public view (spec validation names these ranges)


@dataclasses.dataclass(frozen=True)
class FixedPointConfig:
    """Static (hashable) configuration of the fixed-point controller; see the module docstring.

    cordic_iterations    CORDIC micro-rotations per sin/cos, atan2, sqrt (hyperbolic: incl.
                         the repeated iterations 4, 13).
    cordic_guard_bits    extra fraction bits inside CORDIC registers.
    coef_bits            word length of the coefficient registers (params-derived constants).
    rounding             "nearest" (add half LSB, floor) or "truncate" (floor), for every
                         rounding of the datapath; CORDIC shifts always truncate (wiring).
    ik_guard_bits        extra fraction bits of the IK's internal length words (pelvis-frame
                         ankle position, leg-plane length L', ankle distance D), capped so the
                         word stays <= 26 bits. The knee moves 22 rad per metre of D at the
                         stand pose, so D rounded to the 7.6 um length LSB alone costs
                         0.17 mrad (0.11 servo LSB); 4 bits cut that 16-fold.
    latency_ticks        whole control periods between sensor read and servo command (delay
                         line in the state).
    latency_frac         extra fraction of a period [0, 1): the sim applies the previous
                         command for that fraction of the tick (`servo_switch_substep`).
    straight_through     carry a float shadow of the controller for gradients (value exactly
                         the fixed-point one, gradient the float controller's). Costs one float
                         controller evaluation per tick; switch off when no gradient is taken.
    """

    angle: QFormat = QFormat(2, 15)
    rate: QFormat = QFormat(5, 12)
    length: QFormat = QFormat(0, 17)
    accel: QFormat = QFormat(3, 14)
    unit: QFormat = QFormat(2, 15)
    state: QFormat = QFormat(2, 21)
    cov: QFormat = QFormat(-3, 20)
    coef_bits: int = 18
    cordic_iterations: int = 16
    cordic_guard_bits: int = 2
    rounding: str = "nearest"
    ik_guard_bits: int = 4
    latency_ticks: int = 0
    latency_frac: float = 0.0
    straight_through: bool = True

    def __post_init__(self):
        self.validate()

    @classmethod
    def wide(cls, **changes) -> FixedPointConfig:
        """Near-float words (25-26 bits, 28 iterations): for checking against the float twin."""
        base = dict(angle=QFormat(2, 23), rate=QFormat(5, 20), length=QFormat(0, 25),
                    accel=QFormat(3, 22), unit=QFormat(2, 23), state=QFormat(2, 23),
                    cov=QFormat(-3, 28), coef_bits=28, cordic_iterations=28,
                    cordic_guard_bits=3)
        base.update(changes)
        return cls(**base)

    def validate(self) -> FixedPointConfig:
        """Raise ValueError naming the field and its allowed range; returns self."""
        def bad(name, rng, got):
            raise ValueError(f"FixedPointConfig.{name} must be {rng}, got {got!r}")

        for name, (lo, hi) in _INT_BITS.items():
            f = getattr(self, name)
            if not isinstance(f, QFormat) or not all(
                    isinstance(v, int) and not isinstance(v, bool)
                    for v in (f.int_bits, f.frac_bits)):
                bad(name, "a QFormat(int_bits, frac_bits) of ints", f)
            if not lo <= f.int_bits <= hi:
                bad(f"{name}.int_bits", f"in [{lo}, {hi}]", f.int_bits)
            if not 1 <= f.frac_bits or not 4 <= f.word_bits <= MAX_GROUP_WORD_BITS:
                bad(f"{name}.frac_bits", f"in [1, {MAX_GROUP_WORD_BITS - 1 - f.int_bits}] "
                    f"(word 1 + int + frac in [4, {MAX_GROUP_WORD_BITS}])", f.frac_bits)
        ints = {"coef_bits": (12, 31), "cordic_iterations": (1, 30), "cordic_guard_bits": (0, 3),
                "ik_guard_bits": (0, 8), "latency_ticks": (0, 100)}
        for name, (lo, hi) in ints.items():
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
                bad(name, f"an int in [{lo}, {hi}]", v)
        if self.rounding not in ROUNDING_MODES:
            bad("rounding", f"one of {ROUNDING_MODES}", self.rounding)
        lf = self.latency_frac
        if not isinstance(lf, (int, float)) or isinstance(lf, bool) or not 0.0 <= lf < 1.0 \
                or math.isnan(lf):
            bad("latency_frac", "a float in [0, 1)", lf)
        if not isinstance(self.straight_through, bool):
            bad("straight_through", "a bool", self.straight_through)
        return self

    @property
    def ik_length(self) -> QFormat:
        """Format of the IK's internal lengths: `length` with ik_guard_bits more fraction bits
        (fewer where the word would pass MAX_GROUP_WORD_BITS)."""
        extra = max(0, min(self.ik_guard_bits, MAX_GROUP_WORD_BITS - self.length.word_bits))
        return QFormat(self.length.int_bits, self.length.frac_bits + extra)

    @property
    def latency_periods(self) -> float:
        """Total sensor-to-servo latency in control periods."""
        return self.latency_ticks + float(self.latency_frac)


def servo_switch_substep(config: FixedPointConfig, substeps: int) -> int:
    """Physics substep of a tick at which the new command replaces the previous one.

    The fraction of a tick is realised at the physics time step: round(latency_frac *
    substeps) in [0, substeps] (e.g. 15 substeps of 2 ms: 2 ms resolution).
    """
    if not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps must be an int >= 1, got {substeps!r}")
    return min(substeps, int(math.floor(config.latency_frac * substeps + 0.5)))
