"""The architecture holds: the import graph points down the layers of docs/ARCHITECTURE.md, the simulator
imports nothing of the agent, and no module grows past the size a reader can hold in mind."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("joint_model", "protocol", "sim_controller", "edge_monitor")
#: Layers from the bottom; a module may import from its own layer and the ones below, never above.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("joint_model", "protocol"),
    ("sim_controller", "edge_monitor.errors", "edge_monitor.records", "edge_monitor.schemas"),
    ("edge_monitor.stats",),
    ("edge_monitor.features",),
    ("edge_monitor.sinks",),
    ("edge_monitor.pipeline", "edge_monitor.historian"),
    ("edge_monitor.config", "edge_monitor.app"),
    ("edge_monitor.offline",),
    ("edge_monitor.commands", "edge_monitor.cli", "edge_monitor"),
)
#: Lines a module may have (docs/ARCHITECTURE.md: "no module over ~400 lines").
MAX_LINES = 420


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


def _layer(module: str) -> int:
    best, best_len = None, -1
    for i, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = i, len(prefix)
    assert best is not None, f"{module} is in no layer of LAYERS"
    return best


def _imports(path: Path, module: str) -> set[str]:
    """Project modules imported anywhere in the file (also inside functions)."""
    found: set[str] = set()
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            found.add(base)
    return {name for name in found if name.split(".")[0] in PACKAGES}


def test_every_import_points_down_the_layers():
    upward = []
    for module, path in _modules().items():
        for target in _imports(path, module):
            if _layer(target) > _layer(module):
                upward.append(f"{module} (layer {_layer(module)}) imports {target} (layer {_layer(target)})")
    assert not upward, "\n".join(sorted(upward))


def test_the_running_agent_never_imports_the_simulator():
    """Only the offline studies (and tools) may drive the agent with the simulator."""
    for module, path in _modules().items():
        if module.startswith(("edge_monitor.pipeline", "edge_monitor.features", "edge_monitor.stats",
                              "edge_monitor.sinks")):
            assert not any(t.startswith("sim_controller") for t in _imports(path, module)), module


@pytest.mark.parametrize("package, allowed", [
    ("sim_controller", {"sim_controller", "joint_model", "protocol"}),
    ("protocol", {"protocol"}),
    ("joint_model", {"joint_model"}),
])
def test_the_simulator_and_the_shared_layers_import_nothing_of_the_agent(package, allowed):
    for module, path in _modules().items():
        if module.split(".")[0] == package:
            assert {t.split(".")[0] for t in _imports(path, module)} <= allowed, module


def test_no_module_is_longer_than_a_reader_can_hold():
    long = {str(p.relative_to(ROOT)): n for p in _modules().values()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert not long, long
