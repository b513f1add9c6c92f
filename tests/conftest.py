"""Test-wide set-up: headless GL, persistent XLA cache (MJX compiles are slow on CPU), and the
`compiles` fixture: a count of the programs JAX lowers for compilation."""

import pytest

from tkujax.cli.runtime import configure_runtime

# The command line's own set-up: headless rendering through EGL where libEGL exists (elsewhere
# rendering tests skip), and the persistent XLA cache in TKUJAX_CACHE_DIR.
configure_runtime()

import jax  # noqa: E402

# Every program jit lowers for compilation (a jit-cache miss; a persistent-cache hit is lowered
# too) emits this event; counted by program name from the start of the session.
_LOWERED_EVENT = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_lowered: list[str] = []


def _on_duration(event: str, duration: float, **kwargs) -> None:
    if event == _LOWERED_EVENT:
        _lowered.append(str(kwargs.get("fun_name", "")))


jax.monitoring.register_event_duration_secs_listener(_on_duration)


class CompileCounter:
    """Programs lowered for compilation since the fixture was made (or `reset()`)."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self._start = len(_lowered)

    @property
    def names(self) -> list[str]:
        return _lowered[self._start:]

    @property
    def count(self) -> int:
        return len(self.names)


@pytest.fixture
def compiles() -> CompileCounter:
    return CompileCounter()


@pytest.fixture(autouse=True, scope="module")
def release_compiled_programs():
    """After each test file, drop the compiled programs JAX keeps in memory. A worker runs
    many files one after another (`--dist loadfile`), and their MJX programs add up to
    several GB per worker on a 24 GB machine; a later file reads its programs back from the
    persistent compilation cache."""
    yield
    jax.clear_caches()
