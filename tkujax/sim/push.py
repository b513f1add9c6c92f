"""Pushes: a calibrated horizontal impulse on the torso, and the paper's ball rig.

Impulse pulse: force F(t) = J (pi / 2 tau) sin(pi (t - t0) / tau) on [t0, t0 + tau), whose
integral is exactly J. Direction by azimuth: 0 deg = pushed from behind (toward +x), 90 deg =
pushed from the right (toward +y). It acts at a point of the torso's (chest body's) central
axis at `height_m` above the floor in the stand pose (shifting the point along the force's
line does not change the moment), through `xfrc_applied`, so the rollout is differentiable in
every field.

Ball rig (paper Sec. 4, Fig. 12, Table 3): a ball on a pendulum released from 45 deg. The
paper's "forces" 0.47 N and 0.93 N are m g (1 - cos 45 deg) of its two balls; the falling time
0.34 s fixes the pendulum length; the ball arrives with momentum m v, delivered to the robot as
an impulse. `ball_push` turns a ball name into that impulse.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller_params import CONTROL_PERIOD_S

G = 9.81
RELEASE_ANGLE_RAD = math.radians(45.0)
FALLING_TIME_S = 0.34               # paper Table 3: release to impact
PAPER_ONSET_S = 0.75                # paper Sec. 4: hit at 0.75 s
DEFAULT_HEIGHT_M = 0.36             # mid-chest of the stand pose [est]; the rig's ball height
DEFAULT_DURATION_S = 0.020          # ball-on-robot contact time [est]
PHYSICS_DT_S = 0.002                # the model's time step (tkujax.model: 2 ms)
MAX_IMPULSE_NS = 200.0              # a 50 kg robot's falls need tens of N s
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.05, 2.0
# A push sequence's per-pulse fields (shape (k,) each); its height and duration are shared.
PULSE_FIELDS = ("impulse_ns", "azimuth_rad", "onset_s")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Push:
    """One push (every field a scalar; batch by stacking). SI units, radians.

    kick_mps: a velocity kick instead of a force pulse (None: the half-sine pulse): at onset_s
    the floating base's horizontal velocity (its free joint's qvel[0:2], world frame) jumps by
    kick_mps toward azimuth_rad, as MuJoCo Playground's locomotion tasks push their robots;
    impulse_ns, height_m and duration_s are then unused (`kick_velocity`)."""

    impulse_ns: jax.Array
    azimuth_rad: jax.Array
    height_m: jax.Array
    duration_s: jax.Array
    onset_s: jax.Array
    kick_mps: jax.Array | None = None


def make_push(impulse_ns: float, azimuth_deg: float = 0.0, height_m: float = DEFAULT_HEIGHT_M,
              duration_s: float = DEFAULT_DURATION_S, onset_s: float = PAPER_ONSET_S) -> Push:
    """A Push from user units, validated (ValueError names the bad argument)."""
    # Any humanoid: 0.5-1.8 m tall, 3-50 kg (a sweep also checks the height against its robot).
    checks = [("impulse_ns", impulse_ns, 0.0, MAX_IMPULSE_NS),
              ("height_m", height_m, MIN_HEIGHT_M, MAX_HEIGHT_M),
              ("duration_s", duration_s, 0.002, 0.5), ("onset_s", onset_s, 0.0, 30.0),
              ("azimuth_deg", azimuth_deg, -360.0, 360.0)]
    for name, value, lo, hi in checks:
        if not (isinstance(value, (int, float)) and lo <= value <= hi):
            raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {value!r}")
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    return Push(f(impulse_ns), f(math.radians(azimuth_deg)), f(height_m), f(duration_s), f(onset_s))


def onset_from_phase(onset_s, phase, period: float = CONTROL_PERIOD_S):
    """Onset (s) at `phase` in [0, 1) of the control period: tick + phase * period, where tick
    is the last controller tick at or before onset_s (ticks at k * period from t = 0; the
    1e-6 absorbs the float error of 0.75 / 0.03). numpy or python floats."""
    tick = period * np.floor(np.asarray(onset_s) / period + 1e-6)
    return tick + np.asarray(phase) * period


def onset_phase(onset_s, period: float = CONTROL_PERIOD_S):
    """Phase in [0, 1) of an onset within the control period (the inverse of the above)."""
    x = np.asarray(onset_s) / period
    frac = x - np.floor(x + 1e-6)
    return np.where(frac < 0, 0.0, frac)


def peak_on_sample_phase(duration_s: float = DEFAULT_DURATION_S,
                         period: float = CONTROL_PERIOD_S, dt: float = PHYSICS_DT_S) -> float:
    """The phase whose pulse peak lands on the controller's IMU sample.

    The sample a tick reads at d.time = k * period is the sensordata of the last physics step,
    computed from the state at k * period - dt under the force F(k * period - dt) (both
    backends). The half-sine peaks at onset + duration / 2, so the peak is sampled when
    phase = 1 - (duration / 2 + dt) / period (mod 1): 0.6 for the 20 ms push. The sample sees
    some of the pulse for phase in (1 - (dt + duration) / period, 1 - dt / period], i.e.
    (0.27, 0.93] for 20 ms; phase 0 (an onset on a tick, as the paper's 0.75 s) is never sampled.
    """
    return float(np.mod(1.0 - (0.5 * duration_s + dt) / period, 1.0))


def kick_velocity(push: Push, t, dt: float) -> jax.Array:
    """(2,) the base's horizontal velocity change (m/s) of a velocity kick in the physics step
    that starts at time t (s) and lasts dt: kick_mps toward azimuth_rad when |t - onset_s| <
    dt / 2, else 0 (each pulse of a sequence on its own)."""
    hit = jnp.abs(t - push.onset_s) < 0.5 * dt
    dv = jnp.where(hit, push.kick_mps, 0.0)
    vec = jnp.stack([dv * jnp.cos(push.azimuth_rad), dv * jnp.sin(push.azimuth_rad)], -1)
    return vec if vec.ndim == 1 else jnp.sum(vec, 0)


def first_onset(push: Push) -> jax.Array:
    """The onset (s) of a push, or of a sequence's first pulse (the outcomes count from it);
    of a batch too (a sequence's onsets have one axis more than its height)."""
    seq = jnp.ndim(push.onset_s) > jnp.ndim(push.height_m)
    return push.onset_s[..., 0] if seq else push.onset_s


def stack_pushes(pushes: list[Push]) -> Push:
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *pushes)


def force_at(push: Push, t: jax.Array) -> jax.Array:
    """(3,) world force (N) of the half-sine pulse at time t (s). A push sequence (impulse_ns,
    azimuth_rad and onset_s of shape (k,): k pulses of the push's height and duration) sums
    its pulses' forces."""
    if push.kick_mps is not None:         # a velocity kick: no force (a Python branch on None)
        return jnp.zeros((3,), jnp.result_type(push.azimuth_rad))
    if jnp.ndim(push.impulse_ns) > jnp.ndim(push.height_m):   # a sequence (a static shape)
        pulse = jax.vmap(lambda j, a, o: force_at(dataclasses.replace(
            push, impulse_ns=j, azimuth_rad=a, onset_s=o), t))
        return jnp.sum(pulse(push.impulse_ns, push.azimuth_rad, push.onset_s), 0)
    phase = (t - push.onset_s) / push.duration_s
    active = (phase >= 0.0) & (phase < 1.0)
    magnitude = push.impulse_ns * (jnp.pi / (2.0 * push.duration_s)) * jnp.sin(jnp.pi * phase)
    magnitude = jnp.where(active, magnitude, 0.0)
    return magnitude * jnp.stack([jnp.cos(push.azimuth_rad), jnp.sin(push.azimuth_rad),
                                  jnp.zeros_like(push.azimuth_rad)])


@dataclasses.dataclass(frozen=True)
class Ball:
    name: str
    mass_kg: float
    volume_cm3: float

    @property
    def radius_m(self) -> float:
        return (3.0 * self.volume_cm3 * 1e-6 / (4.0 * math.pi)) ** (1.0 / 3.0)

    @property
    def paper_force_n(self) -> float:
        """The paper's reported "force": m g (1 - cos 45 deg)."""
        return self.mass_kg * G * (1.0 - math.cos(RELEASE_ANGLE_RAD))


BALLS = {"baseball": Ball("baseball", 0.160, 179.0),
         "volleyball": Ball("volleyball", 0.320, 2799.0)}
PAPER_FORCE_N = {"baseball": 0.47, "volleyball": 0.93}   # as reported in Table 3


def pendulum_length_m(falling_time_s: float = FALLING_TIME_S,
                      release_rad: float = RELEASE_ANGLE_RAD) -> float:
    """Pendulum length whose quarter swing from `release_rad` lasts `falling_time_s`.

    Quarter period of a pendulum of amplitude a: (pi/2) sqrt(L/g) (2/pi) K(sin(a/2)), with K
    the complete elliptic integral of the first kind (computed by the AGM).
    """
    k = math.sin(release_rad / 2.0)
    a, b = 1.0, math.sqrt(1.0 - k * k)
    for _ in range(30):
        a, b = 0.5 * (a + b), math.sqrt(a * b)
    big_k = math.pi / (2.0 * a)
    return G * (falling_time_s / big_k) ** 2


def ball_speed_m_s(length_m: float | None = None, release_rad: float = RELEASE_ANGLE_RAD) -> float:
    """Speed at the bottom of the swing: sqrt(2 g L (1 - cos a))."""
    length_m = pendulum_length_m() if length_m is None else length_m
    return math.sqrt(2.0 * G * length_m * (1.0 - math.cos(release_rad)))


def ball_momentum_ns(ball: str) -> float:
    """Momentum m v (N s) the paper's ball carries at impact."""
    return BALLS[_ball(ball)].mass_kg * ball_speed_m_s()


@dataclasses.dataclass(frozen=True)
class BallContact:
    """Where the paper's ball meets the robot and how much of its momentum it transfers.

    height_m         contact height above the floor of the hit from behind. [fit] 0.405 m
                     (upper chest), bound 0.28-0.43 m (anywhere on the chest); estimate
                     DEFAULT_HEIGHT_M.
    impulse_factor   impulse delivered / ball momentum m v = (1 + e) / (1 + m / M_eff), hit
                     from behind. [fit] 1.365, bound 0.9-1.5 (restitution e 0.2-0.6); estimate
                     1.0. tkujax.sim.ball_rig's rigid rig predicts 1.02-1.12: the fit asks for a
                     livelier ball. The data pin only the product height x impulse (the
                     angular impulse about the ankles), not the two separately.
    front_height_offset_m, front_impulse_ratio
                     the hit from the front relative to the one from behind: its contact height
                     minus height_m (the result kept on the chest, CHEST_RANGE_M), and its
                     impulse factor over impulse_factor. The ball meets the chest's front and
                     back, whose shapes and stiffness differ; the paper gives neither contact.
                     [fit] +2 cm and x1.075, in the middle of 0..+3 cm (the chest's top)
                     and x1.0..1.15, where all 8 paper rows hold at all 15 hit phases with the
                     default IMU (results/calibration/imu_bandwidth). 0 and 1: one hit for
                     both directions.
    """

    height_m: float = 0.405
    impulse_factor: float = 1.365
    front_height_offset_m: float = 0.02
    front_impulse_ratio: float = 1.075

    @classmethod
    def estimated(cls) -> BallContact:
        """Before calibration: mid-chest, the ball's momentum exactly, one hit for both."""
        return cls(DEFAULT_HEIGHT_M, 1.0, 0.0, 1.0)

    def validate(self) -> BallContact:
        if not (0.28 <= self.height_m <= 0.43):
            raise ValueError(f"BallContact.height_m must be in [0.28, 0.43] m, "
                             f"got {self.height_m!r}")
        if not (0.9 <= self.impulse_factor <= 1.5):
            raise ValueError(f"BallContact.impulse_factor must be in [0.9, 1.5], "
                             f"got {self.impulse_factor!r}")
        if not (-0.05 <= self.front_height_offset_m <= 0.05):
            raise ValueError(f"BallContact.front_height_offset_m must be in [-0.05, 0.05] m, "
                             f"got {self.front_height_offset_m!r}")
        if not (0.8 <= self.front_impulse_ratio <= 1.25):
            raise ValueError(f"BallContact.front_impulse_ratio must be in [0.8, 1.25], "
                             f"got {self.front_impulse_ratio!r}")
        return self

    def contact_height_m(self, direction: str = "back") -> float:
        """The contact height (m) of the hit from `direction` ("back" or "front")."""
        if _direction(direction) == "back":
            return self.height_m
        lo, hi = CHEST_RANGE_M
        return min(max(self.height_m + self.front_height_offset_m, lo), hi)

    def impulse_ns(self, ball: str, direction: str = "back") -> float:
        """The impulse (N s) this contact delivers for the paper's `ball` from `direction`."""
        ratio = self.front_impulse_ratio if _direction(direction) == "front" else 1.0
        return self.impulse_factor * ratio * ball_momentum_ns(ball)

    def push(self, ball: str, direction: str, onset_s: float = PAPER_ONSET_S,
             duration_s: float = DEFAULT_DURATION_S) -> Push:
        """The paper's case `ball` from `direction` as a Push."""
        return make_push(self.impulse_ns(ball, direction), DIRECTIONS[direction],
                         height_m=self.contact_height_m(direction), onset_s=onset_s,
                         duration_s=duration_s)


CHEST_RANGE_M = (0.275, 0.435)   # the chest's height range in the stand pose, m


def _direction(name: str) -> str:
    if name not in DIRECTIONS:
        raise ValueError(f"direction must be one of {sorted(DIRECTIONS)}, got {name!r}")
    return name


def _ball(name: str) -> str:
    if name not in BALLS:
        raise ValueError(f"ball must be one of {sorted(BALLS)}, got {name!r}")
    return name


DIRECTIONS = {"back": 0.0, "front": 180.0}   # hit from the back pushes toward +x


def ball_push(ball: str, direction: str, onset_s: float = PAPER_ONSET_S,
              contact: BallContact = BallContact()) -> Push:
    """The paper's case as an impulse (the ball's momentum times the contact's transfer factor,
    at the contact's height), from the back or the front."""
    return contact.push(ball, _direction(direction), onset_s)
