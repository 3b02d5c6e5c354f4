"""The import rules of docs/architecture.md section 1, read from the code's own imports (``ast``, no
import runs): a core never imports zenoh, the runtime, a shell or a tool; no shell imports another;
the runtime imports no service; the schemas import nothing of the project above them. Every module
of ``schemas/``, ``services/`` and ``sim_bridge/`` has a layer here, so a new one must be placed
before the suite passes. Plain and fast: no zenoh session.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("schemas", "services", "sim_bridge")

SCHEMAS, CONFIG, RUNTIME, CORE, SHELL, SHELL_SUPPORT, TOOL = (
    "schemas",
    "config",
    "runtime",
    "core",
    "shell",
    "shell support",
    "tool",
)

LAYERS: tuple[tuple[str, str], ...] = (
    # (module pattern, layer); the first pattern that matches a module's whole name places it
    (r"schemas(\..*)?", SCHEMAS),
    (r"services\.config", CONFIG),
    (r"services\.runtime(\..*)?", RUNTIME),
    (r"services\.(motor|odometry|localization)\.core", CORE),
    (r"services\.motor\.state", CORE),
    (r"services\.drive\.(scenarios|path_following)", CORE),
    (r"services\.clock\.(sim_time|lockstep|observation)", CORE),
    (r"services\.planar", CORE),
    (r"services\.fleet\.(description|summary)", CORE),
    (r"services\.fleet\.launch", TOOL),
    (r"sim_bridge\.(simulator|robot|world|geometry|latency|display)", CORE),
    (r"services\.ros2\.(core|wire|interfaces|urdf|graph)", CORE),
    (r"services\.(motor|odometry|localization|drive|ros2)\.service", SHELL),
    (r"sim_bridge\.bridge", SHELL),
    (r"services\.service", SHELL_SUPPORT),
    (r"services\.clock\.sim_watch", SHELL_SUPPORT),
    (r"services\.(cli|recording)(\..*)?", TOOL),
    (r"services\.security", TOOL),
    (r"(services|sim_bridge|services\.(motor|odometry|localization|drive|clock|ros2|fleet))", "package"),
)

PROJECT = re.compile(r"(schemas|services|sim_bridge)(\..*)?")


def layer_of(module: str) -> str | None:
    for pattern, layer in LAYERS:
        if re.fullmatch(pattern, module):
            return layer
    return None


def _is(imported: str, prefix: str) -> bool:
    return imported == prefix or imported.startswith(prefix + ".")


def violations(imports: Mapping[str, set[str]]) -> list[str]:
    """Every import that breaks a rule, as ``"<module> imports <imported>: <rule>"``."""
    found: list[str] = []
    for module, imported_modules in sorted(imports.items()):
        layer = layer_of(module)
        if layer is None:
            found.append(f"{module} has no layer: place it in tests/test_layers.py and docs/architecture.md")
            continue
        for imported in sorted(imported_modules):
            imported_layer = layer_of(imported) if PROJECT.fullmatch(imported) else None
            rule = _broken_rule(module, layer, imported, imported_layer)
            if rule:
                found.append(f"{module} imports {imported}: {rule}")
    return found


def _broken_rule(module: str, layer: str, imported: str, imported_layer: str | None) -> str | None:
    project = PROJECT.fullmatch(imported) is not None
    if layer == SCHEMAS and project and imported_layer != SCHEMAS:
        return "the schemas import only msgspec and the standard library"
    if layer == CONFIG and project and imported_layer != SCHEMAS:
        return "the configuration imports only the schemas"
    if layer == RUNTIME and project and imported_layer not in (SCHEMAS, CONFIG, RUNTIME):
        return "the runtime imports no service, core or tool"
    if layer == CORE:
        if _is(imported, "zenoh"):
            return "a core never imports zenoh"
        if imported_layer == RUNTIME:
            return "a core never imports the runtime"
        if imported_layer in (SHELL, SHELL_SUPPORT):
            return "a core never imports a shell"
        if imported_layer == TOOL:
            return "a core never imports a tool"
    if layer in (SHELL, SHELL_SUPPORT):
        if imported_layer == SHELL and imported != module:
            return "no shell imports another"
        if imported_layer == TOOL:
            return "a shell never imports a tool"
    return None


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, module: str) -> Iterator[str]:
    """Every module ``path`` imports, wherever the import statement is (a function, TYPE_CHECKING)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            yield base
            # `from services.recording import record`: the submodule is what is imported
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                if _exists(submodule):
                    yield submodule


def _exists(module: str) -> bool:
    path = ROOT.joinpath(*module.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def project_imports() -> dict[str, set[str]]:
    imports: dict[str, set[str]] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            module = _module_name(path)
            imports[module] = set(_imports(path, module)) - {""}
    return imports


def test_the_code_keeps_the_import_rules():
    assert violations(project_imports()) == []


def test_every_module_of_the_project_has_a_layer():
    imports = project_imports()
    assert {"services.motor.core", "services.motor.service", "sim_bridge.bridge", "services.cli.up"} <= set(imports)
    assert [module for module in imports if layer_of(module) is None] == []


def test_each_service_room_holds_its_shell_and_its_core():
    for service, cores in {
        "motor": ("core", "state"),
        "odometry": ("core",),
        "localization": ("core",),
        "drive": ("scenarios", "path_following"),
    }.items():
        room = ROOT / "services" / service
        assert (room / "service.py").is_file(), service
        for core in cores:
            assert layer_of(f"services.{service}.{core}") == CORE
            assert (room / f"{core}.py").is_file(), (service, core)


def test_the_services_top_level_holds_subpackages_and_a_handful_of_shared_modules():
    modules = sorted(path.name for path in (ROOT / "services").glob("*.py"))
    assert modules == ["__init__.py", "config.py", "planar.py", "security.py", "service.py"]


@pytest.mark.parametrize(
    ("module", "imported", "rule"),
    [
        ("services.motor.core", "zenoh", "a core never imports zenoh"),
        ("services.odometry.core", "zenoh.handlers", "a core never imports zenoh"),
        ("services.drive.scenarios", "services.runtime.node", "a core never imports the runtime"),
        ("services.localization.core", "services.localization.service", "a core never imports a shell"),
        ("sim_bridge.simulator", "sim_bridge.bridge", "a core never imports a shell"),
        ("services.clock.lockstep", "services.clock.sim_watch", "a core never imports a shell"),
        ("services.motor.core", "services.recording.report", "a core never imports a tool"),
        ("services.motor.service", "services.odometry.service", "no shell imports another"),
        ("sim_bridge.bridge", "services.drive.service", "no shell imports another"),
        ("services.drive.service", "services.cli.up", "a shell never imports a tool"),
        ("services.runtime.node", "services.motor.core", "the runtime imports no service, core or tool"),
        ("schemas.keys", "services.config", "the schemas import only msgspec and the standard library"),
    ],
)
def test_a_broken_rule_is_found(module: str, imported: str, rule: str):
    assert violations({module: {imported}}) == [f"{module} imports {imported}: {rule}"]


def test_allowed_edges_are_not_flagged():
    allowed = {
        "services.motor.core": {"services.clock.sim_time", "services.config", "schemas.codec", "msgspec", "math"},
        "services.motor.service": {"services.motor.core", "services.runtime.node", "services.clock.sim_watch", "zenoh"},
        "services.recording.report": {"services.motor.core", "services.drive.scenarios"},
        "sim_bridge.simulator": {"pybullet", "sim_bridge.robot", "services.config"},
    }
    assert violations(allowed) == []


def test_an_unplaced_module_is_named():
    assert violations({"services.newcomer": set()}) == [
        "services.newcomer has no layer: place it in tests/test_layers.py and docs/architecture.md"
    ]
