"""The research scripts (scripts/): each says what it reproduces, their outputs can never
overwrite their inputs, and their plain logic (reading a fit, the sensitivity summary) does
what it says. Nothing here simulates."""

import importlib.util
import json
import math
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"
WITH_OUT = ["check_mjx", "phase_robustness", "probe_sampling", "slices"]


def _load(name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(SCRIPTS))          # the scripts import their _fit helper
    spec = importlib.util.spec_from_file_location(f"tkujax_script_{name}", SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture
def calibration(tmp_path):
    path = tmp_path / "best.json"
    path.write_text(json.dumps({"ALL": {"x": {"leg_kp": 1.0}, "reading": "deviation/latched",
                                        "rows": {}}, "n_candidates": 3}))
    return path


@pytest.mark.parametrize("name", WITH_OUT)
def test_output_that_is_the_input_is_refused(name, calibration, monkeypatch, capsys):
    main = _load(name, monkeypatch).main
    before = calibration.read_text()
    # Also through another spelling of the same path.
    for out in (calibration, calibration.parent / "sub" / ".." / calibration.name):
        with pytest.raises(SystemExit) as exc:
            main([str(calibration), "ALL", "--out", str(out)])
        assert exc.value.code == 2
        assert "is the input" in capsys.readouterr().err
    assert calibration.read_text() == before


@pytest.mark.parametrize("name", WITH_OUT)
def test_out_is_required(name, calibration, monkeypatch, capsys):
    with pytest.raises(SystemExit) as exc:
        _load(name, monkeypatch).main([str(calibration), "ALL"])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err


def test_sensitivity_refuses_its_center_as_output(calibration, monkeypatch, capsys):
    main = _load("sensitivity", monkeypatch).main
    with pytest.raises(SystemExit) as exc:
        main(["--center", str(calibration), "--out", str(calibration)])
    assert exc.value.code == 2 and "is the input" in capsys.readouterr().err


def test_unknown_fit_names_the_fits_there(calibration, monkeypatch):
    fit = _load("_fit", monkeypatch)
    assert fit.load_fit(calibration, "ALL")["reading"] == "deviation/latched"
    with pytest.raises(SystemExit, match=r"no fit 'T4'; fits there: \['ALL'\]"):
        fit.load_fit(calibration, "T4")


def test_trace_validates_the_row(calibration, monkeypatch, capsys):
    main = _load("trace", monkeypatch).main
    with pytest.raises(SystemExit) as exc:
        main([str(calibration), "ALL", "sideways", "volleyball", "on"])
    assert exc.value.code == 2 and "direction" in capsys.readouterr().err


def test_sensitivity_summary(monkeypatch):
    mod = _load("sensitivity", monkeypatch)
    res = {k: dict(fell=i == 1, peak_deg=10.0 + i + 0.004, rec=math.inf if i == 1 else 0.5 + i,
                   phi_peak_deg=-1.234, stand_deg=2.5 + i) for i, k in enumerate(mod.KEYS)}
    s = mod.summary(res)
    assert s["bv_fell"] == 0 and s["bb_fell"] == 1
    assert s["bb_rec"] is None and s["bv_rec"] == 0.5 and s["fv_rec"] == 2.5
    assert s["fb_peak"] == 13.0 and s["bv_phi_past"] == -1.23
    assert s["stand"] == 2.5                     # the lean of the first row


def test_every_script_says_what_it_reproduces():
    """Each research script lives in scripts/ (none under results/) and opens with a docstring
    that names the result it reproduces or the question it answers."""
    import ast

    root = SCRIPTS.parent
    assert not sorted((root / "results").rglob("*.py")), "scripts belong in scripts/"
    for path in sorted(SCRIPTS.glob("*.py")):
        if path.name.startswith("_"):
            continue
        doc = ast.get_docstring(ast.parse(path.read_text()))
        assert doc and len(doc) > 20, f"{path.name} has no docstring"


ALL_SCRIPTS = sorted(p.stem for p in SCRIPTS.glob("*.py"))


@pytest.mark.parametrize("name", ALL_SCRIPTS)
def test_every_script_imports(name, monkeypatch):
    """Importing a script runs nothing (its work sits behind `if __name__ == "__main__"`) and
    fails when a name it imports at the top is gone."""
    monkeypatch.setattr("sys.argv", ["script"])           # a script reading argv would fail
    _load(name, monkeypatch)


def _tkujax_imports(path: Path):
    """(module, name) of every `from tkujax... import name` in the file, nested ones too."""
    import ast

    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "tkujax":
            yield from ((node.module, a.name) for a in node.names)
        elif isinstance(node, ast.Import):
            yield from ((a.name, None) for a in node.names if a.name.split(".")[0] == "tkujax")


@pytest.mark.parametrize("name", ALL_SCRIPTS)
def test_scripts_import_public_names_that_exist(name):
    """Every tkujax name a script imports (inside its functions too) exists and is public."""
    import importlib

    for module, attr in _tkujax_imports(SCRIPTS / f"{name}.py"):
        mod = importlib.import_module(module)
        if attr is None:
            continue
        assert not attr.startswith("_"), f"{name}.py imports the private {module}.{attr}"
        assert hasattr(mod, attr) or importlib.util.find_spec(f"{module}.{attr}"), \
            f"{name}.py imports {module}.{attr}, which is gone"
