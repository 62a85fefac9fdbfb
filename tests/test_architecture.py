"""The architecture holds: the import graph points down the layers of docs/ARCHITECTURE.md, the simulator
imports nothing of the agent, no module grows past the size a reader can hold in mind, and the code outside
the product (the tools, the studies' package) reads it through public names only."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("joint_model", "protocol", "sim_controller", "edge_monitor", "studies")
#: Layers from the bottom; a module may import from its own layer and the ones below, never above.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("joint_model", "protocol"),
    ("sim_controller", "edge_monitor.errors", "edge_monitor.records", "edge_monitor.schemas"),
    ("edge_monitor.stats",),
    ("edge_monitor.features",),
    ("edge_monitor.sinks",),
    ("edge_monitor.sources",),          # bytes → per-joint samples; the pipeline takes them from here
    ("edge_monitor.pipeline", "edge_monitor.historian"),
    # how the agent is built and run: the builder, replay's monitoring process, run failures → exit codes
    ("edge_monitor.config", "edge_monitor.app", "edge_monitor.monitor_process", "edge_monitor.run_failures"),
    ("edge_monitor.offline",),
    ("edge_monitor.commands", "edge_monitor.cli", "edge_monitor"),
    ("studies",),                       # the studies' machinery: above the whole product, not shipped
)
#: Code that reads the product from outside it: command-line tools and the studies' package.
OUTSIDE = ("tools", "studies")
#: The catch-all of the top layer: only the package itself may fall to it, every module has a named layer.
TOP = "edge_monitor"
#: Lines a module may have (docs/ARCHITECTURE.md: "no module over ~400 lines").
MAX_LINES = 420


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


def _placement(module: str) -> tuple[int, str]:
    """The layer of ``module`` and the prefix that puts it there (the longest that matches)."""
    best, best_prefix = None, ""
    for i, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > len(best_prefix):
                best, best_prefix = i, prefix
    assert best is not None, f"{module} is in no layer of LAYERS"
    return best, best_prefix


def _layer(module: str) -> int:
    return _placement(module)[0]


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


def test_every_module_of_the_agent_has_a_named_layer():
    """A new top-level module states its layer in LAYERS instead of falling to the top one (where it could
    import commands: monitor_process once did)."""
    unplaced = [m for m in _modules() if m.startswith(TOP + ".") and _placement(m)[1] == TOP]
    assert not unplaced, f"add these modules to a layer of LAYERS: {unplaced}"


def test_the_running_agent_never_imports_the_simulator():
    """Only the offline studies (and tools) may drive the agent with the simulator."""
    for module, path in _modules().items():
        if module.startswith(("edge_monitor.pipeline", "edge_monitor.sources", "edge_monitor.features",
                              "edge_monitor.stats", "edge_monitor.sinks")):
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


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _own(node: ast.expr) -> bool:
    """``self`` or ``cls``: an object reading its own private fields."""
    return isinstance(node, ast.Name) and node.id in ("self", "cls")


def _private_uses(path: Path, where: str) -> list[str]:
    """Where ``path`` (shown as ``where``) reads, writes or imports a private name of another object or
    module: ``x._name``, ``getattr(x, "_name")`` (also ``setattr``/``hasattr``/``delattr``) and
    ``from m import _name``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Attribute) and _private(node.attr) and not _own(node.value):
            found.append(f"{where}:{node.lineno}: .{node.attr}")
        elif isinstance(node, ast.ImportFrom):
            found += [f"{where}:{node.lineno}: import {a.name}" for a in node.names if _private(a.name)]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("getattr", "setattr", "hasattr", "delattr") and len(node.args) >= 2
              and not _own(node.args[0]) and isinstance(node.args[1], ast.Constant)
              and isinstance(node.args[1].value, str) and _private(node.args[1].value)):
            found.append(f"{where}:{node.lineno}: {node.func.id}(…, {node.args[1].value!r})")
    return found


def test_tools_and_studies_read_the_product_through_public_names_only():
    """A tool or a study that needs a number the product keeps asks for it by a public name (a property,
    a method, a documented attribute); reaching into ``._private`` fields breaks silently when they change."""
    files = [p for folder in OUTSIDE for p in sorted((ROOT / folder).rglob("*.py"))]
    assert len(files) > 40, "tools/ and studies/ not found"
    found = [use for path in files for use in _private_uses(path, str(path.relative_to(ROOT)))]
    assert not found, "\n".join(found)


def test_the_private_access_check_sees_what_it_should(tmp_path: Path):
    sample = tmp_path / "tool.py"
    sample.write_text("from m import _hidden\nx = det._transform\ny = getattr(det, '_glr', None)\n"
                      "self._mine = 1\nz = cls._cache\nw = obj.__class__\n", encoding="utf-8")
    uses = {u.split(": ", 1)[1] for u in _private_uses(sample, "tool.py")}
    assert uses == {"import _hidden", "._transform", "getattr(…, '_glr')"}, uses
