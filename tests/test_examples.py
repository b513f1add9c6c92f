"""examples/: every script runs at its CI size (`--small`) into a temporary folder, the
notebook executes top to bottom, and examples/quickstart.py is the README's Python snippet.
The ones on the MuJoCo C backend take seconds; tune_tiny and quickstart compile MJX (slow)."""

import importlib.util
import os
import re
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def _example(name: str):
    spec = importlib.util.spec_from_file_location(f"tkujax_example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _small(name: str, out: Path):
    return _example(name).main(["--small", "--out", str(out)])


def test_every_example_is_tested_and_documented():
    scripts = sorted(p.stem for p in EXAMPLES.glob("*.py"))
    assert scripts == ["capture_regions", "compare_controllers", "own_robot", "quickstart",
                       "sweep_and_map", "tune_tiny"]
    doc = (ROOT / "docs" / "examples.md").read_text()
    for name in [*scripts, "newcomer"]:
        assert f"examples/{name}." in doc, name
    for name in scripts:
        if name != "quickstart":
            assert "--small" in (EXAMPLES / f"{name}.py").read_text(), name


def test_quickstart_is_the_readme_snippet():
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert (EXAMPLES / "quickstart.py").read_text() in blocks


def test_sweep_and_map(tmp_path, capsys):
    out = tmp_path / "sweep"
    res = _small("sweep_and_map", out)
    assert res["records"]["fell"].size == 16
    assert res["parquet"] == tmp_path / "sweep.parquet" and res["parquet"].is_file()
    assert all(Path(f).is_file() for f in res["maps"]["files"])
    assert "pushes fell" in capsys.readouterr().out


def test_capture_regions(tmp_path):
    res = _small("capture_regions", tmp_path / "capture")
    assert res["complete"] and Path(res["summary"]).is_file()


def test_own_robot(tmp_path):
    res = _small("own_robot", tmp_path / "robot")
    assert (tmp_path / "robot" / "robot" / "my_robot.toml").is_file()
    assert not res["stand"]["fell"] and res["records"]["fell"].size == 8


def test_compare_controllers(tmp_path):
    res = _small("compare_controllers", tmp_path / "compare")
    assert Path(res["summary"]).is_file() and "verdict" in res


def test_newcomer_notebook_executes(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    from nbclient import NotebookClient

    monkeypatch.setenv("TKUJAX_EXAMPLES_SMALL", "1")
    monkeypatch.setenv("TKUJAX_NOTEBOOK_OUT", str(tmp_path / "newcomer"))
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    nb = nbformat.read(EXAMPLES / "newcomer.ipynb", as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(EXAMPLES)}}).execute()
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if "image/png" in o.get("data", {})]
    assert len(images) >= 4                               # three plots and one map
    assert (tmp_path / "newcomer" / "newcomer.parquet").is_file()


@pytest.mark.slow
def test_tune_tiny(tmp_path):
    record = _small("tune_tiny", tmp_path / "tune")
    assert record["iterations"] >= 1 and (tmp_path / "tune" / "summary.md").is_file()


@pytest.mark.slow
def test_quickstart_runs(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", [str(EXAMPLES / "quickstart.py")])
    runpy.run_path(str(EXAMPLES / "quickstart.py"), run_name="__main__")
    out = capsys.readouterr().out
    assert out.count("[") >= 2 and ("True" in out or "False" in out)


def test_examples_write_under_runs_by_default():
    for path in EXAMPLES.glob("*.py"):
        text = path.read_text()
        if "--out" in text:
            assert '"runs"' in text, path.name
    assert "/runs/" in (ROOT / ".gitignore").read_text().split()
    assert os.path.isdir(EXAMPLES)
