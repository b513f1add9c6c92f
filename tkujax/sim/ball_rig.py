"""The paper's ball rig as a physical model, to check the impulse model `tkujax.sim.push.ball_push`.

Liu et al. 2020, Sec. 4 / Table 3 / Fig. 12: a baseball (160 g) or a volleyball (320 g) hangs on
a pendulum, is raised to 45 deg and released; it falls for 0.34 s and hits the robot's chest at
t = 0.75 s, from the back or from the front. `tkujax.sim.push` turns that into a half-sine force
pulse carrying the ball's momentum J = m v (`ball_momentum_ns`). Here the rig itself is built:

* `ball_rig_xml(ball, direction, model_params=None)`: TKU-X (`tkujax.model.model_xml`) plus
  a pendulum: a world-fixed pivot with a hinge about the world y axis (`ball_swing`), a massless
  rod (a visual capsule) of length `pendulum_length_m()` (0.43 m: a 0.34 s quarter swing from
  45 deg) and a sphere of the ball's mass and radius. The ball's inertia about its centre is
  that of a solid sphere (2/5 m r^2) for the baseball and of a thin shell (2/3 m r^2) for the
  inflated volleyball, so the rig is a physical pendulum: it arrives ~0.1 % (baseball) / ~1.4 %
  (volleyball) slower and ~0.3 / ~4 ms later than the point-mass formulas of `tkujax.sim.push`
  (which the paper's "derived facts" use). The pivot is placed so that at the bottom of the
  swing the ball's centre is DEFAULT_HEIGHT_M (0.36 m) above the floor and its surface is
  RIG_GAP_M (1.5 mm) off the `chest` collision box, measured along the box face normal in the
  *compiled* stand keyframe (the chest leans 7 deg forward), behind the robot ("back": the ball
  swings toward +x) or in front of it ("front": toward -x). The only contact the ball can make
  is an explicit `<pair>` ball-chest (every geom of the model has contype = conaffinity = 0),
  with MuJoCo's default pair parameters: condim 3, friction 1, solref (0.02, 1), solimp
  (0.9, 0.95, 0.001). Keyframe "rig": the robot's stand pose and targets, the ball at rest at
  +45 deg ("back") or -45 deg ("front"). (The robot's "stand" key is padded by MuJoCo with the
  hinge's qpos0: the ball hanging at the bottom, 1.5 mm off the chest.)
* `ball_rig_impulse(ball, direction, model_params=None, solref=None)`: MuJoCo C, float64, the
  model's own options (2 ms, Newton, 1 iteration). The robot holds its stand targets (control
  off). Same clock as `tkujax.sim.rollout_mjx`: the rig first settles for 1 s with the ball
  held at 45 deg (its hinge qpos/qvel reset every step; the ball touches nothing, so this does
  not disturb the robot), the clock is reset to 0, the ball stays held until t = 0.75 - 0.34 s
  = 0.41 s and is then released. Returned (a `RigImpulse`): arrival speed and time, the
  momentum the ball delivered m (v_before - v_after), restitution, contact duration, the
  robot's momentum change over the contact window, ...

Measured (default ModelParams, default contact; tests/test_ball_rig.py prints the table):
  case               v_in   t_hit  gap   v_out  delivered  /J     /(m v_in)  e     contact  robot dp
                     m/s    s      mm    m/s    N s                           -     ms       N s
  baseball  back     1.560  0.750  1.1   -0.19  0.281      1.12   1.12       0.16  68       0.122
  baseball  front    1.560  0.750  2.0   -0.14  0.272      1.09   1.09       0.12  78       0.107
  volleyball back    1.541  0.754  1.1   -0.14  0.537      1.07   1.09       0.18  66       0.294
  volleyball front   1.541  0.754  2.0   -0.06  0.512      1.02   1.04       0.11  80       0.237
(J = m v = `ball_momentum_ns`: 0.250 / 0.500 N s; v = `ball_speed_m_s()` = 1.563 m/s; v_out:
ball velocity along the push after contact, negative = bounced back; e: restitution of the
relative normal velocity, ball vs the chest point it touches; gap: after the 1 s settle, the
robot has sagged ~0.6 mm backward.)

What this says about the impulse model. A perfectly inelastic hit on a free 4.5 kg body would
deliver m v M/(M+m) = 0.97 m v (baseball) / 0.93 m v (volleyball); a perfectly elastic one up to
2 m v. MuJoCo's default soft contact (solref (0.02, 1): critically damped, time constant 20 ms)
lands near the inelastic end but slightly *above* m v: the standing robot is not a free body;
its feet hold it through the floor and its servos, so over the long (~70 ms) soft contact it
barely moves, stops the ball, then springs back and returns it at 4-12 % of its speed (e 0.11-
0.18). The ball therefore gives up 1.04-1.12 m v_in; against the impulse model's J (the ideal
point-mass m v) that is delivered / J = 1.02-1.12, i.e. J agrees with the physical rig within
~12 %, J slightly *under*states the rig. Robustness (not in the tests): solref (0.01, 1) (contact
~34 ms) gives 1.01-1.12, (0.004, 1) (8 ms) 1.02-1.20, a converged solver (100 Newton iterations
instead of the model's 1) 1.00-1.12, friction 0.2 instead of 1 1.02-1.09. Don't use underdamped
solrefs near 2 dt (e.g. (0.004, 0.3)): at the 2 ms step they gain energy (e > 1).
Two caveats for the pulse model: (1) the contact lasts 64-84 ms, 3-4x the 20 ms
`DEFAULT_DURATION_S`; (2) during it the floor takes back about half of what the ball gives, so
the robot's own horizontal momentum rises by only 0.39-0.55 of the delivered momentum over the
contact window (`robot_dp_ns`, with the model's 1-iteration solver; a converged solver gives
0.51-0.67). `contact_impulse_ns` (the integral of the ball-chest contact force from efc_force) is
a diagnostic only: with one Newton iteration the reported constraint forces are not exactly the
ones that moved the bodies, and friction at the chest lets the pivot take some horizontal load,
so it exceeds the ball-side number by up to ~30 % (back) and ~10 % (front).
"""

from __future__ import annotations

import copy
import dataclasses
import functools

import mujoco
import numpy as np

from tkujax.model import ModelParams, model_xml
from tkujax.sim.push import (BALLS, DEFAULT_HEIGHT_M, FALLING_TIME_S, PAPER_ONSET_S,
                             RELEASE_ANGLE_RAD, ball_momentum_ns, ball_speed_m_s,
                             pendulum_length_m)
from tkujax.sim.records import Columns

__all__ = ["RIG_GAP_M", "RIG_DIRECTIONS", "BALL_INERTIA_FACTOR", "RigGeometry", "RigImpulse",
           "rig_geometry", "ball_rig_xml", "ball_rig_model", "ball_rig_impulse"]

RIG_GAP_M = 0.0015              # ball surface to chest box at the bottom of the swing
RIG_DIRECTIONS = {"back": 1.0, "front": -1.0}   # sign of the push along world x
# Moment of inertia about the ball's centre, in units of m r^2: a baseball is a solid sphere
# (cork/rubber core wound in yarn), a volleyball an inflated thin shell.
BALL_INERTIA_FACTOR = {"baseball": 2.0 / 5.0, "volleyball": 2.0 / 3.0}
SETTLE_S = 1.0                  # as `tkujax.sim.setup.init`: robot settled 1 s, clock reset
RELEASE_S = PAPER_ONSET_S - FALLING_TIME_S   # 0.41 s: the ball is let go then, hits at ~0.75 s
AFTER_S = 0.4                   # simulated after the first contact (to catch a second hit)


def _check(ball: str, direction: str) -> None:
    if ball not in BALLS:
        raise ValueError(f"ball must be one of {sorted(BALLS)}, got {ball!r}")
    if direction not in RIG_DIRECTIONS:
        raise ValueError(f"direction must be one of {sorted(RIG_DIRECTIONS)}, got {direction!r}")


@dataclasses.dataclass(frozen=True)
class RigGeometry:
    """Where the pendulum goes (world frame, m, rad)."""

    pivot: tuple[float, float, float]
    length_m: float
    radius_m: float
    release_angle_rad: float     # hinge angle of the "rig" keyframe (+45 deg back, -45 deg front)
    face_normal: tuple[float, float, float]   # outward normal of the chest face that is hit


@functools.lru_cache(maxsize=32)
def rig_geometry(ball: str, direction: str, model_params: ModelParams | None = None,
                 gap_m: float = RIG_GAP_M) -> RigGeometry:
    """Pivot placement from the compiled stand keyframe (mj_forward), not nominal dimensions.

    The hit face of the chest box is the plane n . x = c (n its outward normal, tilted by the
    stand lean); the ball's bottom-of-swing centre p = (x, 0, DEFAULT_HEIGHT_M) is put at
    n . p - c = r + gap, and the pivot straight above it by the pendulum length.
    """
    _check(ball, direction)
    model = mujoco.MjModel.from_xml_string(model_xml(model_params))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("stand").id)
    mujoco.mj_forward(model, data)
    g = model.geom("chest").id
    centre, rot = data.geom_xpos[g].copy(), data.geom_xmat[g].reshape(3, 3)
    half = model.geom_size[g]
    sign = RIG_DIRECTIONS[direction]
    normal = -sign * rot[:, 0]                # back face: -x_chest; front face: +x_chest
    c = float(normal @ (centre + half[0] * normal))
    radius = BALLS[ball].radius_m
    y, z = float(centre[1]), DEFAULT_HEIGHT_M
    # n_x x + n_y y + n_z z - c = r + gap
    x = (radius + gap_m + c - normal[1] * y - normal[2] * z) / normal[0]
    p = np.array([x, y, z])
    # The nearest point of the box must lie on that face, not on an edge.
    local = rot.T @ (p - centre)
    if abs(local[1]) > half[1] or abs(local[2]) > half[2]:
        raise ValueError(f"ball centre at height {z} m is not in front of the chest face "
                         f"(box-frame offset {local})")
    length = pendulum_length_m()
    return RigGeometry(pivot=(x, y, z + length), length_m=length, radius_m=radius,
                       release_angle_rad=sign * RELEASE_ANGLE_RAD,
                       face_normal=tuple(float(v) for v in normal))


def ball_rig_xml(ball: str, direction: str, model_params: ModelParams | None = None) -> str:
    """TKU-X plus the ball pendulum, a ball-chest contact pair and the "rig" keyframe (MJCF).

    Hinge `ball_swing` about world +y (qpos: the last entry; 0 = ball at the bottom; a positive
    angle swings the ball toward -x); bodies `ball_pendulum` (the pivot) and `ball` (its centre);
    geom `ball`. The "rig" key: the stand pose and ctrl plus the ball at rest at the release angle.
    """
    _check(ball, direction)
    b, geo = BALLS[ball], rig_geometry(ball, direction, model_params)
    length, r = geo.length_m, geo.radius_m
    inertia = BALL_INERTIA_FACTOR[ball] * b.mass_kg * r * r
    f = lambda v: " ".join(f"{x:.9g}" for x in v)  # noqa: E731
    pendulum = f"""
    <body name="ball_pendulum" pos="{f(geo.pivot)}">
      <joint name="ball_swing" type="hinge" axis="0 1 0"/>
      <geom name="ball_rod" type="capsule" fromto="0 0 0 0 0 {-(length - r):.9g}" size="0.002"
            class="visual" rgba="0.3 0.3 0.3 1"/>
      <body name="ball" pos="0 0 {-length:.9g}">
        <inertial pos="0 0 0" mass="{b.mass_kg:.9g}" diaginertia="{f([inertia] * 3)}"/>
        <geom name="ball" type="sphere" size="{r:.9g}" group="1" rgba="0.95 0.85 0.2 1"/>
      </body>
    </body>
  </worldbody>"""
    xml = model_xml(model_params)
    for tag in ("</worldbody>", "</contact>", "</keyframe>"):
        if xml.count(tag) != 1:
            raise RuntimeError(f"model_xml has {xml.count(tag)} {tag} tags, expected 1")
    xml = xml.replace("</worldbody>", pendulum)
    xml = xml.replace("</contact>", '  <pair name="ball_chest" geom1="ball" geom2="chest" '
                      'condim="3"/>\n  </contact>')
    robot = mujoco.MjModel.from_xml_string(model_xml(model_params))
    key = robot.key("stand")
    qpos = np.concatenate([key.qpos, [geo.release_angle_rad]])
    rig_key = f'<key name="rig" qpos="{f(qpos)}" ctrl="{f(key.ctrl)}"/></keyframe>'
    return xml.replace("</keyframe>", rig_key)


@functools.lru_cache(maxsize=32)
def ball_rig_model(ball: str, direction: str,
                   model_params: ModelParams | None = None) -> mujoco.MjModel:
    """The compiled rig (cached; copy it before changing fields)."""
    return mujoco.MjModel.from_xml_string(ball_rig_xml(ball, direction, model_params))


def _ball_in_contact(model: mujoco.MjModel, data: mujoco.MjData, ball: int, chest: int) -> bool:
    for i in range(data.ncon):
        g1, g2 = data.contact.geom1[i], data.contact.geom2[i]
        if {g1, g2} == {ball, chest}:
            return True
        if ball in (g1, g2):
            raise RuntimeError(f"ball touches geom {model.geom(int(g1 + g2 - ball)).name!r}")
    return False


@dataclasses.dataclass(frozen=True)
class RigImpulse(Columns):
    """What `ball_rig_impulse` measured (SI units); rec["name"] reads a field too.

    Velocities and momenta are along the push direction s (+1 "back": +x, -1 "front": -x).
      ball, direction, sign (s), ball_mass_kg, robot_mass_kg,
      gap_m: ball-chest distance with the ball at the bottom of its swing, settled robot;
      expected_speed_m_s (`ball_speed_m_s()`), expected_time_s (0.75);
      arrival_speed_m_s: |ball velocity| just before the first contact; contact_time_s: then;
      v_before_m_s / v_after_m_s: ball velocity along s just before the first contact / just
        after the last ball-chest contact ends (negative: the ball bounced back);
      delivered_ns: m (v_before - v_after), the momentum the ball gave up, along s;
      delivered_x_ns: the same along world x (its sign is the direction's);
      contact_impulse_ns: the time integral of the ball-chest contact force on the robot along s,
        from efc_force (a diagnostic: see the module doc; it differs from delivered by the
        pivot's horizontal reaction and, with the model's 1 Newton iteration, by solver error);
      impulse_model_ns: J = `ball_momentum_ns(ball)` = m v, what `ball_push` applies;
      ratio: delivered / J; ratio_to_arrival: delivered / (m v_before);
      v_ratio: v_after / v_before; restitution: (chest point's v_after - ball's v_after) over
        (ball's v_before - chest point's v_before), the chest point facing the ball;
      contact_duration_s: first contact to the end of the last one; n_contacts: separate contact
        episodes up to 0.4 s after the first (1: a single hit); first_contact_duration_s;
      robot_dp_ns: change of the robot's horizontal momentum (total mass x CoM velocity, along s)
        over the contact window; floor_impulse_ns: robot_dp - delivered, mostly the floor's
        friction impulse over that window (negative: the feet resist the push);
      peak_force_n: largest ball-chest normal force.
    """

    ball: str
    direction: str
    sign: float
    ball_mass_kg: float
    robot_mass_kg: float
    gap_m: float
    expected_speed_m_s: float
    expected_time_s: float
    arrival_speed_m_s: float
    contact_time_s: float
    v_before_m_s: float
    v_after_m_s: float
    delivered_ns: float
    delivered_x_ns: float
    contact_impulse_ns: float
    impulse_model_ns: float
    ratio: float
    ratio_to_arrival: float
    v_ratio: float
    restitution: float
    contact_duration_s: float
    n_contacts: int
    first_contact_duration_s: float
    robot_dp_ns: float
    floor_impulse_ns: float
    peak_force_n: float


@dataclasses.dataclass(frozen=True)
class _Trace:
    """Per-step records of the swing (read before each step's contact force acts)."""

    t: np.ndarray
    ball_v: np.ndarray       # ball velocity along world x
    chest_v: np.ndarray      # velocity of the chest point facing the ball, along world x
    robot_p: np.ndarray      # robot's horizontal momentum along world x
    contact: list            # ball-chest contacts of each step
    force_s: list            # ball-chest contact force on the robot along s
    force_n: list            # its normal force
    first: int               # first step in contact


def _swing(model: mujoco.MjModel, data: mujoco.MjData, hold, s: float, normal: np.ndarray,
           radius: float, m_robot: float, ball: str, direction: str) -> _Trace:
    """Release the ball at RELEASE_S and step until AFTER_S after the first contact. Each step
    is split (mj_step1 / mj_step2) so that the contact flag, the ball's velocity and the
    robot's momentum are read at one state, before that step's contact force acts."""
    ball_body, chest_body = model.body("ball").id, model.body("chest").id
    pelvis = model.body("pelvis").id
    ball_geom, chest_geom = model.geom("ball").id, model.geom("chest").id
    dt = float(model.opt.timestep)
    vel6 = np.zeros(6)
    t, ball_v, chest_v, robot_p, contact, force_s, force_n = [], [], [], [], [], [], []
    first = None
    n_release = int(round(RELEASE_S / dt))
    n_max = n_release + int(round((FALLING_TIME_S + 0.2 + AFTER_S) / dt))
    for i in range(n_max):
        if i < n_release:
            hold()
        mujoco.mj_step1(model, data)
        mujoco.mj_subtreeVel(model, data)
        contact.append(_ball_contacts(model, data, ball_geom, chest_geom))
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, ball_body, vel6, 0)
        ball_v.append(float(vel6[3]))
        # The chest's material point facing the ball: ball centre - r n.
        point = data.xpos[ball_body] - radius * normal
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, chest_body, vel6, 0)
        chest_v.append(float((vel6[3:] + np.cross(vel6[:3], point - data.xpos[chest_body]))[0]))
        robot_p.append(m_robot * float(data.subtree_linvel[pelvis][0]))
        t.append(float(data.time))
        mujoco.mj_step2(model, data)       # efc_force: the forces that acted during this step
        fx, fn = _chest_force(model, data, contact[-1], chest_geom)
        force_s.append(s * fx)
        force_n.append(fn)
        if contact[-1] and first is None:
            first = i
        if first is not None and i - first >= int(round(AFTER_S / dt)):
            break
    if first is None:
        raise RuntimeError(f"{ball} from the {direction}: the ball never touched the chest")
    t, ball_v, chest_v, robot_p = map(np.asarray, (t, ball_v, chest_v, robot_p))
    return _Trace(t, ball_v, chest_v, robot_p, contact, force_s, force_n, first)


def ball_rig_impulse(ball: str, direction: str, model_params: ModelParams | None = None,
                     solref: tuple[float, float] | None = None) -> RigImpulse:
    """Swing the ball into the standing robot (MuJoCo C, float64, control off) and measure.

    Time t: the `tkujax.sim.rollout_mjx` clock (0 after 1 s of settling); the ball is released at
    t = 0.41 s. `solref` overrides the ball-chest pair's (default MuJoCo's (0.02, 1)).
    Returns a RigImpulse (its docstring defines every field).
    """
    _check(ball, direction)
    model = ball_rig_model(ball, direction, model_params)
    if solref is not None:
        model = copy.deepcopy(model)
        model.pair_solref[model.pair("ball_chest").id] = solref
    data = mujoco.MjData(model)
    key = model.key("rig")
    mujoco.mj_resetDataKeyframe(model, data, key.id)
    data.ctrl[:] = key.ctrl
    hinge = model.joint("ball_swing")
    qadr, vadr = int(hinge.qposadr[0]), int(hinge.dofadr[0])
    angle0 = float(key.qpos[qadr])
    ball_body, pelvis = model.body("ball").id, model.body("pelvis").id
    m_ball, m_robot = float(model.body_mass[ball_body]), float(model.body_subtreemass[pelvis])
    s = RIG_DIRECTIONS[direction]
    geo = rig_geometry(ball, direction, model_params)
    dt = float(model.opt.timestep)

    def hold():
        data.qpos[qadr], data.qvel[vadr] = angle0, 0.0

    for _ in range(int(round(SETTLE_S / dt))):
        hold()
        mujoco.mj_step(model, data)
    data.time = 0.0
    hold()
    mujoco.mj_forward(model, data)
    gap = _gap_at_bottom(model, data, qadr, model.geom("ball").id, model.geom("chest").id)
    tr = _swing(model, data, hold, s, np.asarray(geo.face_normal), geo.radius_m, m_robot, ball,
                direction)
    first = tr.first
    on = np.flatnonzero([bool(c) for c in tr.contact])
    breaks = np.flatnonzero(np.diff(on) > 1)
    first_end = int(on[breaks[0]] + 1) if breaks.size else int(on[-1] + 1)
    last = int(on[-1] + 1)                   # first record after the last contact
    if last >= len(tr.t):
        raise RuntimeError(f"{ball} from the {direction}: the ball still touches the chest "
                           f"{AFTER_S} s after the first contact")
    v_before, v_after = s * tr.ball_v[first], s * tr.ball_v[last]
    delivered = m_ball * (v_before - v_after)
    robot_dp = s * (tr.robot_p[last] - tr.robot_p[first])
    j = ball_momentum_ns(ball)
    return RigImpulse(
        ball=ball, direction=direction, sign=s, ball_mass_kg=m_ball, robot_mass_kg=m_robot,
        gap_m=gap, expected_speed_m_s=ball_speed_m_s(), expected_time_s=PAPER_ONSET_S,
        arrival_speed_m_s=abs(float(tr.ball_v[first])), contact_time_s=float(tr.t[first]),
        v_before_m_s=float(v_before), v_after_m_s=float(v_after),
        delivered_ns=float(delivered), delivered_x_ns=float(s * delivered),
        contact_impulse_ns=dt * float(np.sum(tr.force_s[first:last])), impulse_model_ns=j,
        ratio=float(delivered / j), ratio_to_arrival=float(delivered / (m_ball * v_before)),
        v_ratio=float(v_after / v_before),
        restitution=float((s * tr.chest_v[last] - v_after) / (v_before - s * tr.chest_v[first])),
        contact_duration_s=float(tr.t[last] - tr.t[first]), n_contacts=int(breaks.size + 1),
        first_contact_duration_s=float(tr.t[first_end] - tr.t[first]),
        robot_dp_ns=float(robot_dp), floor_impulse_ns=float(robot_dp - delivered),
        peak_force_n=float(max(tr.force_n)))


def _ball_contacts(model: mujoco.MjModel, data: mujoco.MjData, ball: int, chest: int) -> list:
    """Indices of the ball-chest contacts; raises if the ball touches anything else."""
    out = []
    for i in range(data.ncon):
        g1, g2 = int(data.contact.geom1[i]), int(data.contact.geom2[i])
        if {g1, g2} == {ball, chest}:
            out.append(i)
        elif ball in (g1, g2):
            raise RuntimeError(f"the ball touches geom {model.geom(g1 + g2 - ball).name!r}")
    return out


def _chest_force(model: mujoco.MjModel, data: mujoco.MjData, contacts: list,
                 chest: int) -> tuple[float, float]:
    """(world x force on the chest, largest normal force) of the given contacts, N."""
    fx, fn, f6 = 0.0, 0.0, np.zeros(6)
    for i in contacts:
        mujoco.mj_contactForce(model, data, i, f6)
        world = data.contact.frame[i].reshape(3, 3).T @ f6[:3]   # force of geom1 on geom2
        fx += float(world[0]) * (1.0 if data.contact.geom2[i] == chest else -1.0)
        fn = max(fn, float(f6[0]))
    return fx, fn


def _gap_at_bottom(model: mujoco.MjModel, data: mujoco.MjData, qadr: int, ball_geom: int,
                   chest_geom: int) -> float:
    """Ball-chest distance with the ball at the bottom of its swing, robot as in `data`."""
    probe = mujoco.MjData(model)
    probe.qpos[:] = data.qpos
    probe.qpos[qadr] = 0.0
    mujoco.mj_kinematics(model, probe)
    return float(mujoco.mj_geomDistance(model, probe, ball_geom, chest_geom, 0.1, None))
