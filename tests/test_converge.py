"""`tkujax converge`: spec validation, the agreement arithmetic on hand-made
outcomes, and a tiny MuJoCo C run (2 settings x (8 paper rows + 2 x 2 pushes), ~15 s on a CPU)."""

import json

import numpy as np
import pytest

from tkujax import cli
from tkujax.studies import converge as C
from tkujax.dialects.sweep_spec import SpecError

TINY = """
[converge]
name = "tiny"
batch = 12
reference = "a"
[[converge.setting]]
name = "a"
timestep_ms = 2.0
[[converge.setting]]
name = "b"
timestep_ms = 2.0
[[converge.setting]]
name = "c"
timestep_ms = 3.0
[paper]
phases = 1
[wide]
pushes = 2
"""


def _spec(**over):
    base = {"converge": {"setting": [{"timestep_ms": 1.0}, {"timestep_ms": 2.0}]}}
    for k, v in over.items():
        table, key = k.split(".")
        base.setdefault(table, {})[key] = v
    return base


@pytest.mark.parametrize("key, value, words", [
    ("converge.backend", "gpu", "converge.backend"),
    ("converge.batch", 0, "converge.batch"),
    ("converge.reference", "nope", "converge.reference"),
    ("paper.phases", 101, "paper.phases"),
    ("wide.pushes", -1, "wide.pushes"),
    ("wide.impulse_ns", [1.8, 0.2], "wide.impulse_ns"),
    ("wide.height_m", 0.1, "wide.height_m"),
])
def test_spec_errors_name_the_key_and_range(key, value, words):
    with pytest.raises(SpecError, match=words.replace(".", r"\.")):
        C.parse_spec(_spec(**{key: value}))


def test_spec_setting_checks():
    with pytest.raises(SpecError, match=r"setting\[0\]\.timestep_ms must divide"):
        C.parse_spec({"converge": {"setting": [{"timestep_ms": 0.7}, {"timestep_ms": 2.0}]}})
    with pytest.raises(SpecError, match=r"timestep_ms must be a number in \[0.5, 10.0\]"):
        C.parse_spec({"converge": {"setting": [{"timestep_ms": 20.0}, {"timestep_ms": 2.0}]}})
    with pytest.raises(SpecError, match="at least twice"):
        C.parse_spec({"converge": {"setting": [{"timestep_ms": 2.0}]}})
    with pytest.raises(SpecError, match="distinct"):
        C.parse_spec({"converge": {"setting": [{"timestep_ms": 2.0}, {"timestep_ms": 2.0}]}})
    with pytest.raises(SpecError, match="unknown key"):
        C.parse_spec({"converge": {"setting": [{"timestep_ms": 2.0, "dt": 1},
                                               {"timestep_ms": 1.0}]}})


def test_default_reference_is_the_finest():
    s = C.parse_spec({"converge": {"setting": [
        {"timestep_ms": 2.0}, {"timestep_ms": 1.0, "solver_iterations": 1},
        {"timestep_ms": 1.0, "solver_iterations": 4, "ls_iterations": 8}]}})
    assert s.reference == "1ms-newton4-ls8"
    assert s.setting("2ms-newton1-ls4").model_params().timestep_s == pytest.approx(0.002)


def test_shipped_specs_parse():
    for path, backend in (("specs/converge/convergence.toml", "mjx"),
                          ("specs/converge/convergence_cpu.toml", "mujoco")):
        s = C.load_spec(path)
        assert s.backend == backend and s.reference == "0.5ms-newton4-ls8"
        assert {x.timestep_ms for x in s.settings} == {0.5, 1.0, 2.0, 3.0}
        assert s.setting("2ms-newton1-ls4").model_params() == __import__(
            "tkujax.model", fromlist=["ModelParams"]).ModelParams()      # today's default
        assert s.phases == 15 and s.impulse_ns == (0.2, 1.8)


def test_wilson_interval_known_values():
    # 95 % Wilson interval of 95/100: (0.8882, 0.9785) (textbook value)
    lo, hi = C.wilson(95, 100)
    assert lo == pytest.approx(0.8882, abs=1e-4) and hi == pytest.approx(0.9785, abs=1e-4)
    assert C.wilson(10, 10)[1] == 1.0


def test_agreement_counts_by_hand():
    spec = C.parse_spec({"converge": {"setting": [{"name": "r", "timestep_ms": 1.0},
                                                  {"name": "s", "timestep_ms": 2.0}]},
                         "paper": {"phases": 0}, "wide": {"pushes": 4}})
    labels = dict(set=np.array(["wide"] * 8), control=np.array(["off"] * 4 + ["on"] * 4),
                  phase=np.zeros(8), row=np.full(8, -1))
    z = np.zeros(8)
    ref = dict(fell=np.array([0, 1, 0, 1, 0, 0, 1, 1], bool), diverged=np.zeros(8, bool),
               step_length_m=z.copy())
    # off: one flip (push 1); on: push 7 diverged in s, push 4 flips
    s = dict(fell=np.array([0, 0, 0, 1, 1, 0, 1, 1], bool),
             diverged=np.array([0, 0, 0, 0, 0, 0, 0, 1], bool),
             step_length_m=np.array([0, 0, 0, 0, 0, 0.02, 0, 0]))
    agr = C.agreement(spec, labels, {"r": ref, "s": s})
    off, on = agr["s"]["wide_off"], agr["s"]["wide_on"]
    assert (off["agree"], off["n"], off["diverged"]) == (3, 4, 0)
    assert (on["agree"], on["n"], on["diverged"]) == (2, 3, 1)
    assert on["max_step_change_cm"] == pytest.approx(2.0)
    assert agr["r"]["wide_on"]["fraction"] == 1.0


def test_tiny_run_mujoco(tmp_path):
    spec_path = tmp_path / "tiny.toml"
    spec_path.write_text(TINY)
    out = tmp_path / "out"
    assert cli.main(["converge", str(spec_path), "--out", str(out), "--only", "a,b"]) == 0
    assert not (out / "outcomes_c.npz").exists()
    assert cli.main(["converge", str(spec_path), "--out", str(out)]) == 0     # resumes: c only
    agr = json.loads((out / "agreement.json").read_text())["settings"]
    assert set(agr) == {"a", "b", "c"}
    # b is a with another name: the backend is deterministic, so it agrees everywhere
    for k in ("wide_off", "wide_on", "paper_off", "paper_on"):
        assert agr["b"][k]["fraction"] == 1.0 and agr["b"][k]["max_step_change_cm"] == 0.0
    # the default robot at phase 0 holds the paper's 8 fall outcomes at 2 ms
    assert agr["a"]["paper_as_paper"]["phase0"] == 8
    assert "| a (ref.) |" in (out / "agreement.md").read_text()
    # the report against another setting, without running anything
    assert cli.main(["converge", str(spec_path), "--out", str(out), "--no-run",
                     "--reference", "c"]) == 0
    vs_c = json.loads((out / "agreement_vs_c.json").read_text())["settings"]
    assert vs_c["c"]["wide_on"]["fraction"] == 1.0
    assert vs_c["a"]["wide_off"]["agree"] == agr["c"]["wide_off"]["agree"]   # symmetric
    assert cli.main(["converge", str(spec_path), "--out", str(out), "--no-run",
                     "--reference", "zz"]) == 2
    # a different spec in the same folder is refused, naming spec.json
    spec_path.write_text(TINY.replace("pushes = 2", "pushes = 3"))
    assert cli.main(["converge", str(spec_path), "--out", str(out)]) == 2
