"""`tkujax tune SPEC --out DIR`: tune the recovery step and the push detection through the MJX
rollout with one of four methods (`tune.method`, `search.py`): CMA-ES (the default), Adam on
gradients through the rollout, their hybrid (the alpha-order mix of first-order and
zeroth-order gradients), or the (1+1)-ES baseline; a spec's [compare] runs several of them
over seeds at one wall-clock budget. The result is evaluated with the hard controller on
held-out (and shifted) pushes.

Parameterisations (`tune.policy`, tkujax.studies.tune.parameterisations): "scalars" (the default:
the
fields of `tune.params`), "sectorsN", "mlp[H]" and "mlpr[H]" (the scalars plus corrections
of the `tune.schedule` fields as functions of the controller's filtered state, and for "mlpr"
of its recovery state too, tkujax.control.policy).
A [study] table runs the dimension study (policies x methods x seeds,
tkujax.studies.tune.dimension_study;
its seeds optionally side by side in one batch, tkujax.studies.tune.lockstep).

Tuned (the spec's `tune.params` chooses; ControllerParams field names):
  step_period (T, s), double_support_ratio (gamma), lift_height (H_Sup, m), eps_forward and
  eps_backward (epsilon_1, epsilon_2, rad), and optionally cp_gain, kalman_q, kalman_r.

Reparameterisation (never clipped after a step): optax updates an unconstrained latent z per
parameter; the value is lo + (hi - lo) sigmoid(z) for linear parameters and
10^(log10 lo + (log10 hi - log10 lo) sigmoid(z)) for the Kalman variances. Default ranges
(`DEFAULT_RANGES`, user units; a spec's [tune.ranges] may narrow or move them within the
ranges ControllerParams.validate allows, tkujax.control.params_files):
  step_period [0.15, 0.6] s, double_support_ratio [0, 0.6], lift_height [0.005, 0.06] m,
  eps_forward [8, 24] deg (absolute pitch; the robot stands at ~7 deg), eps_backward [0, 12] deg,
  cp_gain [0.3, 2.5], kalman_q [1e-6, 1e-2] rad^2 (log), kalman_r [1e-4, 3e-2] rad^2 (log).

Loss (mean over a fixed batch of pushes, all terms dimensionless; `LossConfig`):
  fall      softplus((fall_margin_m - m) / fall_width_m), m = soft minimum over time of the
            clearance above the fall thresholds of tkujax.sim.metrics (lowest non-foot body point
            above 5 mm, pelvis above 0.12 m): ~0 while standing (m ~ 0.1 m), ~10 when fallen.
  recovery  time average after onset of log(1 + (deviation / incl_ref)^2), deviation = the true
            pelvis inclination (pitch and roll) from its pre-push value: the squared deviation
            integrated over time, saturating so a fallen push does not drown the batch.
  step      sqrt(x_Sup^2 + y_Sup^2 + 1 mm^2) / step_ref: a small cost on the step length.
  loss = w_fall fall + w_recovery recovery + w_step step.
For the gradient methods the detection gate is soft: gate_temperature follows the spec's
annealing schedule (geometric or linear from start_deg to end_deg), so gradients reach
eps_1/eps_2; CMA-ES and the (1+1)-ES search the hard-gate loss. The
step's start is still the discrete instant at which the step weight crosses 1/2 (see
tkujax.control.controller), so the gradient sees the step's length and shape, not its timing.

Gradient notes (checked against central finite differences in float64, tests/test_tune.py):
  - Servo quantisation (tkujax.sim) makes the leg targets piecewise constant in the parameters;
    its straight-through gradient is deliberate, so finite differences only agree with the
    gradient with `quantise_targets=False` (tune.quantise_targets, default true as in sweeps).
  - At the paper's T = 0.3 s, gamma = 0.2 the lift-off (gamma T / 2) and landing instants fall
    exactly on 30 ms control ticks, where the loss has a kink in T and gamma: the gradient there
    is one-sided.
  - jax.checkpoint (remat) on each control tick gives the same gradient (1e-14 relative) and is
    what makes 1,024 pushes x 1.5 s fit on one GPU (2.7 GiB peak vs 125 GiB requested without).
    tune.remat = true now checkpoints each physics substep instead (problem.TUNE_REMAT): on one
    H100, 1.55 GB peak and 2.98 s a step against 2.93 GB and 4.63 s per tick.

Robots and harm (tkujax.studies.tune.tune_spec, problem): [randomize] ensemble = "PATH"
runs every training and held-out push on one member of a calibration ensemble, drawn
uniformly (last, so specs without it draw the same pushes as before); [evaluate.shift]
ensemble runs the shifted set on one. One RobotSet holds the default robot (row 0) and the
members (rows 1..n); each record's robot_id row is picked inside the one compiled loss. Without
an ensemble the program is the single-robot one. tune.loss.w_harm > 0 multiplies a push's loss
by (1 + w_harm) when control OFF survives it (a per-push column computed once per batch by a
control-off forward pass: loss.harm_weighted_mean); the evaluation then also reports the
harmed rate (falls with control, survives without).

Gradient optimiser: optax chain(clip_by_global_norm, adam) on the latents. A non-finite loss or
gradient is counted, logged in history.json and skipped: neither the latents nor Adam's moments
change.

Evaluation (after tuning, always with the HARD controller, gate_temperature = 0): held-out
pushes drawn from the same distribution with another seed (never used for tuning), and a grid
of impulses x azimuths: fall rate, mean recovery time, max recoverable impulse per direction
(tkujax.analysis.maps.max_recoverable_impulse), hard loss, for the parameters before and after
tuning.

Writes history.json, params_before.json and params_after.json (in the format
tkujax.control.params_files.load_controller_params_json reads), loss_curve.png, evaluation.png,
summary.md.
"""

from __future__ import annotations

from tkujax.studies.tune.held_out_gate import evaluate, params_json
from tkujax.studies.tune.loss import LOSS_FIELDS, LossConfig, harm_weighted_mean, push_loss
from tkujax.studies.tune.methods import (evolution_baseline, make_optimizer, optimise,
                                         temperature_schedule)
from tkujax.studies.tune.benchmark import benchmark_gradient_step
from tkujax.studies.tune.parameterisations import PolicyReparam, parse_policy
from tkujax.studies.tune.problem import RECORD_KEYS, TuneProblem
from tkujax.studies.tune.lockstep import run_search_lockstep
from tkujax.studies.tune.reparam import (DEFAULT_RANGES, DEFAULT_TUNED, DEG, TUNABLE, Reparam)
from tkujax.studies.tune.tune_outputs import summary_markdown
from tkujax.studies.tune.search import METHODS, SearchConfig, alpha_order_mix, run_search
from tkujax.studies.tune.tune_command import run_tune
from tkujax.studies.tune.dimension_study import run_study
from tkujax.studies.tune.tune_spec import (TuneSpec, grid_pushes, load_tune_spec, make_problem,
                                           parse_tune_spec, robot_table, sample_pushes)

__all__ = ["DEFAULT_RANGES", "DEFAULT_TUNED", "DEG", "LOSS_FIELDS", "RECORD_KEYS", "TUNABLE",
           "LossConfig", "Reparam", "TuneProblem", "TuneSpec", "benchmark_gradient_step",
           "evaluate", "evolution_baseline", "grid_pushes", "load_tune_spec", "make_optimizer",
           "optimise", "params_json", "parse_tune_spec", "push_loss", "run_tune",
           "sample_pushes", "summary_markdown", "temperature_schedule", "METHODS", "SearchConfig",
           "alpha_order_mix", "run_search", "run_search_lockstep", "PolicyReparam",
           "parse_policy", "run_study", "harm_weighted_mean", "make_problem", "robot_table"]
