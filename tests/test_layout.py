"""The package layout: imports go one way (model <- control <- sim <- studies <- cli), the public
API resolves, and the typed records expose the columns sweeps write."""

import ast
from pathlib import Path

import pytest

import tkujax

ROOT = Path(tkujax.__file__).parent
LAYERS = ["model", "control", "sim", "studies", "top"]   # top: bench, render, cli (packages too)


def _layer(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "tkujax" or len(parts) == 1:
        return ""
    return parts[1] if parts[1] in LAYERS else "top"


def _imports(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module
        elif isinstance(node, ast.Import):
            yield from (a.name for a in node.names)


@pytest.mark.parametrize("path", sorted(ROOT.rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_only_go_down_the_layers(path):
    rel = path.relative_to(ROOT)
    own = rel.parts[0] if len(rel.parts) > 1 and rel.parts[0] in LAYERS else "top"   # cli/
    if rel.name == "__init__.py" and len(rel.parts) == 1:
        return                                  # tkujax/__init__.py: the lazy public API
    for mod in _imports(path):
        layer = _layer(mod)
        if layer:
            assert LAYERS.index(layer) <= LAYERS.index(own), f"{rel} imports {mod} (a higher layer)"


def test_public_api_resolves():
    """Each public name is the object of the module the table names (no stand-in), and an
    unknown name is an AttributeError naming it."""
    import importlib
    from importlib import metadata

    for name in tkujax.__all__:
        if name == "__version__":
            continue
        module = importlib.import_module(tkujax._API[name])
        assert getattr(tkujax, name) is getattr(module, name)
        assert callable(getattr(tkujax, name)), name          # classes and functions
    assert tkujax.__version__ == metadata.version("tkujax")
    with pytest.raises(AttributeError, match="no attribute 'simulat'"):
        tkujax.simulat  # noqa: B018


def test_records_are_typed_pytrees_with_columns():
    import jax
    import numpy as np

    from tkujax.sim.records import OUTCOME_FIELDS, Outcomes

    o = Outcomes(**{k: np.arange(3.0) for k in OUTCOME_FIELDS})
    assert o.fell is o["fell"] and list(o) == list(OUTCOME_FIELDS)
    doubled = jax.tree_util.tree_map(lambda x: 2 * x, o)
    assert isinstance(doubled, Outcomes) and doubled.columns()["step_length_m"][2] == 4.0
    with pytest.raises(KeyError, match="no column 'nope'"):
        o["nope"]


def test_compile_counter_sees_compiles_and_cache_hits(compiles):
    """The `compiles` fixture (conftest.py) that the no-recompile checks rely on: a new program
    counts once, calling it again (a jit-cache hit) counts nothing."""
    import jax
    import numpy as np

    f = jax.jit(lambda x: 3.0 * x + 1.0)
    assert compiles.count == 0
    f(np.arange(3.0))
    assert compiles.count == 1
    f(np.arange(3.0) + 1.0)
    assert compiles.count == 1
    f(np.arange(4.0))                                     # a new shape: a new program
    assert compiles.count == 2
