"""The package layout: imports go one way (model <- control <- sim <- robot <- studies <- cli),
no import cycle, no module over 500 lines nor function over 80, no private name imported from
another module, the public API resolves, the typed records expose the columns sweeps write, and
one function (tkujax.sim.robot.as_robot) resolves what a caller gives for a robot."""

import ast
from pathlib import Path

import pytest

import tkujax

ROOT = Path(tkujax.__file__).parent
LAYERS = ["model", "control", "sim", "robot", "gradients", "walking", "dialects", "sweeps",
          "analysis", "studies", "top"]   # top: bench, viewer, render, cli


def _layer(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "tkujax" or len(parts) == 1:
        return ""
    return parts[1] if parts[1] in LAYERS else "top"


def _imports(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "tkujax" and node.level == 0:
            yield from (f"tkujax.{a.name}" for a in node.names)    # from tkujax import render
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
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


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _module_graph() -> dict[str, set[str]]:
    """tkujax module -> the tkujax modules it imports at the top (not inside functions: those
    run late, which is how a lazy import breaks a cycle)."""
    paths = {_module_name(p): p for p in ROOT.rglob("*.py")}
    graph = {}
    for name, path in paths.items():
        deps = set()
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                deps |= {m for m in (f"{node.module}.{a.name}" for a in node.names)
                         if m in paths} or ({node.module} & paths.keys())
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names} & paths.keys()
        graph[name] = deps - {name}
    return graph


def test_no_import_cycle():
    """No tkujax module reaches itself through its top-level imports."""
    graph = _module_graph()
    done, stack = set(), []

    def visit(name):
        if name in stack:
            raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(name):]
                                                                  + [name]))
        if name in done:
            return
        stack.append(name)
        for dep in sorted(graph[name]):
            visit(dep)
        stack.pop()
        done.add(name)

    for name in sorted(graph):
        visit(name)


MAX_MODULE_LINES, MAX_FUNCTION_LINES = 500, 80
SOURCES = sorted(ROOT.rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_modules_and_functions_are_small(path):
    rel = path.relative_to(ROOT)
    text = path.read_text()
    assert len(text.splitlines()) <= MAX_MODULE_LINES, f"{rel}: over {MAX_MODULE_LINES} lines"
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            assert n <= MAX_FUNCTION_LINES, \
                f"{rel}:{node.lineno} {node.name}: {n} lines (over {MAX_FUNCTION_LINES})"


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_private_name_is_imported_from_another_module(path):
    """No `from tkujax.x import _y` outside x itself."""
    own, rel = _module_name(path), str(path.relative_to(ROOT))
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "tkujax" and node.module != own:
            private = {a.name for a in node.names
                       if a.name.startswith("_") and not a.name.startswith("__")}
            assert not private, f"{rel} imports {sorted(private)} from {node.module}"


def _isinstance_names(tree: ast.AST):
    """(function name, class names) of every isinstance(x, ...) call, by enclosing function."""
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "isinstance" \
                    and len(node.args) == 2:
                kinds = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
                yield fn.name, {getattr(k, "id", getattr(k, "attr", "")) for k in kinds}


def test_the_robot_is_resolved_in_one_place():
    """What a caller gives for a robot (a Robot, ModelParams or None) is sorted out by one
    function, tkujax.sim.robot.as_robot: no other module asks whether a value is a Robot."""
    sites = [(str(path.relative_to(ROOT)), fn)
             for path in SOURCES for fn, names in _isinstance_names(ast.parse(path.read_text()))
             if names & {"Robot", "RobotSetup"}]
    assert sites == [("sim/robot.py", "as_robot")]
