"""Per-push outcomes from a rollout's control-rate series (pure JAX, vmap-able).

Definitions (the band and thresholds are arguments, defaults documented here):
  fell             the pelvis dropped below 0.12 m, or any non-foot collision geom (knees, hands,
                   head, chest, pelvis) came within 5 mm of the floor, at any period.
  recovery_time_s  from the push onset until the true pelvis inclination returns to, and then
                   stays within, band_deg (default 1 deg) of its standing value (mean pitch and
                   roll over the `baseline_s` before onset; the deviation is hypot(d pitch,
                   d roll), so sideways pushes count); 0 if it never left the band; NaN if it
                   fell or is still outside at the end.
  recovery_time_pitch_s  the same reading on the pelvis pitch alone, |d pitch| (the paper's
                   phi, "pitch-axis", Figs. 13-16): a roll offset that persists after a step
                   (the swing foot lands a little off the line) keeps recovery_time_s "not
                   settled" while the pitch has settled. Both come from `_recovery_time`, so the
                   two differ only in the deviation they read; the MJX and MuJoCo C backends
                   share this function.
  step_length_m    displacement of the swing (left) ankle along x, end minus onset; step_width_m
                   the same along y.
  peak_incl_deg    largest inclination deviation (as above) after onset, degrees.
  zmp_excursion_m  largest distance of the ZMP (sole sensors' centre of pressure) from its
                   standing position after onset.
  capture_point_m  x_Sup latched by the controller (0 when no push was detected);
                   capture_point_y_m the lateral y_Sup (0 unless lateral steps are on).
  diverged         the simulation blew up: a non-finite value anywhere in the series, or a
                   CoM or pelvis (height) speed between successive samples above
                   DIVERGED_SPEED_M_S = 20 m/s. Why 20: a 56 cm robot toppling from standing
                   reaches sqrt(2 g 0.3 m) = 2.4 m/s, and the largest spec impulse (10 N s on
                   4.5 kg) gives 2.2 m/s, so 20 m/s is ~8x anything physical: only numerical
                   blow-up crosses it. A diverged push also has fell = True (NaN is never read as
                   survived), but maps, summaries and tuning count it apart, never as fell or
                   survived.
"""

from __future__ import annotations

import jax.numpy as jnp

from tkujax.sim.records import Outcomes, Series

RECOVERY_BAND_DEG = 1.0
FALL_PELVIS_HEIGHT_M = 0.12
FALL_BODY_CLEARANCE_M = 0.005
DIVERGED_SPEED_M_S = 20.0


def fall_indicator(series: Series) -> jnp.ndarray:
    """(n_ticks,) bool: fallen at each period. Written as "not standing" so that NaN (all of
    whose comparisons are False) counts as fallen, never as survived."""
    return ~((series["pelvis_z"] >= FALL_PELVIS_HEIGHT_M)
             & (series["lowest_body_z"] >= FALL_BODY_CLEARANCE_M))


def diverged_indicator(series: Series, bound_m_s: float = DIVERGED_SPEED_M_S) -> jnp.ndarray:
    """() bool: any non-finite float in the series, or a CoM / pelvis-height speed between
    successive samples above `bound_m_s` (see the module docstring)."""
    finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(v)) for _, v in series.items()
                                if jnp.issubdtype(jnp.asarray(v).dtype, jnp.floating)]))
    dt = jnp.maximum(jnp.diff(series["t"]), 1e-6)
    com_speed = jnp.linalg.norm(jnp.diff(series["com"], axis=0), axis=-1) / dt
    pelvis_speed = jnp.abs(jnp.diff(series["pelvis_z"])) / dt
    too_fast = jnp.any(com_speed > bound_m_s) | jnp.any(pelvis_speed > bound_m_s)
    return ~finite | too_fast


def _recovery_time(t, dev, after, fell, onset_s, band_deg):
    """Time from onset until `dev` (deg, per period) re-enters and stays within band_deg: 0 if it
    never left, NaN if fell or still outside at the last period (see the module docstring)."""
    outside = after & (dev > band_deg)
    # Last period outside the band (-1 if none); recovered when the next period exists.
    idx = jnp.arange(t.shape[0])
    last_out = jnp.max(jnp.where(outside, idx, -1))
    recovered = (last_out < t.shape[0] - 1) & ~fell
    t_back = t[jnp.minimum(last_out + 1, t.shape[0] - 1)]
    recovery = jnp.where(last_out < 0, 0.0, t_back - onset_s)
    return jnp.where(recovered, recovery, jnp.nan)


def outcomes(series: Series, onset_s, band_deg: float = RECOVERY_BAND_DEG,
             baseline_s: float = 0.3) -> Outcomes:
    """Outcomes of one rollout (series fields (n_ticks, ...)); see the module docstring."""
    t = series["t"]
    pitch_deg, roll_deg = jnp.degrees(series["pitch"]), jnp.degrees(series["roll"])
    before = (t <= onset_s) & (t > onset_s - baseline_s)
    after = t > onset_s
    n_before = jnp.maximum(jnp.sum(before), 1)
    standing = jnp.sum(jnp.where(before, pitch_deg, 0.0)) / n_before
    standing_roll = jnp.sum(jnp.where(before, roll_deg, 0.0)) / n_before
    # hypot written out with a floor so its gradient at zero deviation is finite.
    dev = jnp.sqrt((pitch_deg - standing) ** 2 + (roll_deg - standing_roll) ** 2 + 1e-12)

    fell = jnp.any(fall_indicator(series))
    recovery = _recovery_time(t, dev, after, fell, onset_s, band_deg)
    recovery_pitch = _recovery_time(t, jnp.abs(pitch_deg - standing), after, fell, onset_s,
                                    band_deg)

    i_onset = jnp.argmax(after)  # first period after onset
    step = series["l_ankle"][-1] - series["l_ankle"][jnp.maximum(i_onset - 1, 0)]
    zmp0 = jnp.sum(jnp.where(before[:, None], series["zmp"], 0.0), 0) / n_before
    zmp_dist = jnp.linalg.norm(series["zmp"] - zmp0, axis=-1)
    return Outcomes(
        fell=fell,
        recovery_time_s=recovery,
        recovery_time_pitch_s=recovery_pitch,
        step_length_m=step[0],
        step_width_m=step[1],
        peak_incl_deg=jnp.max(jnp.where(after, dev, 0.0)),
        zmp_excursion_m=jnp.max(jnp.where(after & (series["fsr_total"] > 1.0), zmp_dist, 0.0)),
        capture_point_m=series["x_sup"][-1],
        capture_point_y_m=series["y_sup"][-1],
        standing_pitch_deg=standing,
        diverged=diverged_indicator(series),
    )


CAPTURE_KEYS = ("touchdown_s", "icp_td_x_m", "icp_td_y_m", "com_td_z_m", "l_ankle0_x_m",
                "l_ankle0_y_m", "r_ankle0_x_m", "r_ankle0_y_m", "l_ankle_td_x_m", "l_ankle_td_y_m",
                "r_ankle_td_x_m", "r_ankle_td_y_m", "final_speed_m_s", "margin_deg")


def capture_outcomes(series: Series, onset_s, gravity: float = 9.81) -> dict:
    """What a capture-region study needs from one rollout (pure JAX, vmap/grad-able).

    touchdown_s: when the executed step landed (the controller's own or the override's; NaN
    if it had not landed by the end). icp_td_*: the LIP instantaneous capture point
    xi = c + cdot / omega at touchdown, world (x, y) m, from the simulated CoM: c linearly
    interpolated between the two control periods around touchdown, cdot their secant, omega =
    sqrt(g / c_z). *_ankle0: the ankles before the push (first period); *_ankle_td: at
    touchdown. final_speed_m_s: horizontal CoM speed over the last period.
    margin_deg: the capture margin the gradient study maximises, minus the RMS inclination
    deviation after onset (deg; about 0 for a robot that barely moved, tens of degrees once
    it falls). Smooth in the step target wherever no contact changes.
    """
    t = series["t"]
    dt = t[1] - t[0]
    com = series["com"]
    td = series["touchdown_s"][-1]
    landed = td <= t[-1]
    # t[k] is the end of period k; find k with t[k] <= td < t[k + 1].
    k = jnp.clip(jnp.floor((td - t[0]) / dt).astype(jnp.int32), 0, t.shape[0] - 2)
    w = jnp.clip((td - t[k]) / dt, 0.0, 1.0)
    c = (1.0 - w) * com[k] + w * com[k + 1]
    cdot = (com[k + 1] - com[k]) / dt
    omega = jnp.sqrt(gravity / jnp.maximum(c[2], 1e-3))
    icp = c[:2] + cdot[:2] / omega
    nan = jnp.nan
    at_td = lambda x: jnp.where(landed, (1.0 - w) * x[k] + w * x[k + 1], nan)  # noqa: E731

    pitch, roll = series["pitch"], series["roll"]
    before = (t <= onset_s) & (t > onset_s - 0.3)
    after = t > onset_s
    n_before = jnp.maximum(jnp.sum(before), 1)
    dp = jnp.degrees(pitch - jnp.sum(jnp.where(before, pitch, 0.0)) / n_before)
    dr = jnp.degrees(roll - jnp.sum(jnp.where(before, roll, 0.0)) / n_before)
    msq = jnp.sum(jnp.where(after, dp**2 + dr**2, 0.0)) / jnp.maximum(jnp.sum(after), 1)
    l_td, r_td = at_td(series["l_ankle"]), at_td(series["r_ankle"])
    return dict(
        touchdown_s=jnp.where(landed, td, nan),
        icp_td_x_m=jnp.where(landed, icp[0], nan), icp_td_y_m=jnp.where(landed, icp[1], nan),
        com_td_z_m=jnp.where(landed, c[2], nan),
        l_ankle0_x_m=series["l_ankle"][0, 0], l_ankle0_y_m=series["l_ankle"][0, 1],
        r_ankle0_x_m=series["r_ankle"][0, 0], r_ankle0_y_m=series["r_ankle"][0, 1],
        l_ankle_td_x_m=l_td[0], l_ankle_td_y_m=l_td[1],
        r_ankle_td_x_m=r_td[0], r_ankle_td_y_m=r_td[1],
        final_speed_m_s=jnp.linalg.norm(com[-1, :2] - com[-2, :2]) / dt,
        margin_deg=-jnp.sqrt(msq + 1e-12))


WALK_KEYS = ("distance_m", "footstep_moved")


def walk_outcomes(series: Series, start_s) -> dict:
    """What a walking sweep records of one rollout (pure JAX, vmap-able): distance_m, the
    CoM's horizontal displacement from the walk's first step (start_s, the last sample at or
    before it) to the last sample before the fall (or the end); footstep_moved, whether the
    walking recovery had moved a footstep at the end (the step weight the controller reports,
    as `tkujax.walking.walk_push` counts them)."""
    t = series["t"]
    n = t.shape[0]
    idx = jnp.arange(n)
    i0 = jnp.clip(jnp.sum(t <= start_s) - 1, 0, n - 1)
    fallen = fall_indicator(series)
    i_end = jnp.where(jnp.any(fallen), jnp.maximum(jnp.argmax(fallen) - 1, i0), n - 1)
    com = series["com"][:, :2]
    disp = jnp.sum(jnp.where((idx == i_end)[:, None], com, 0.0), 0) - com[i0]
    return dict(distance_m=jnp.sqrt(jnp.sum(disp ** 2) + 1e-12),
                footstep_moved=series["step_weight"][-1] > 0.5)
