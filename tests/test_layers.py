"""The import rules of docs/architecture.md section 1, read from the code's own imports (``ast``, no
import runs): a core never imports zenoh, the runtime, a shell or a tool; no shell imports another;
the runtime imports no service; the schemas import nothing of the project above them; nothing but
the command line imports the command line; only the launcher and the command line import the
simulator bridge (``sim_bridge/``); no modules import each other (a circle); no room holds a tool
beside a core or a shell. Every module
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

BASE, SCHEMAS, CONFIG, RUNTIME, CORE, SHELL, SHELL_SUPPORT, TOOL, PACKAGE = (
    "base",
    "schemas",
    "config",
    "runtime",
    "core",
    "shell",
    "shell support",
    "tool",
    "package",
)
COMMAND_LINE = "services.cli"
"""The ``invent`` command line: it sits on top, so nothing but itself imports it."""
SIM_BRIDGE = "sim_bridge"
SIM_BRIDGE_IMPORTERS = ("services.launch", COMMAND_LINE)
"""The only rooms outside ``sim_bridge/`` that import it: the launcher starts the simulator, the
command line lists its flags. Whatever else needs the robot's body takes it from ``services.body``."""

LAYERS: tuple[tuple[str, str], ...] = (
    # (module pattern, layer); the first pattern that matches a module's whole name places it
    (r"schemas(\..*)?", SCHEMAS),
    (r"services\.(errors|exits)", BASE),
    (r"services\.config(\..*)?", CONFIG),
    (r"services\.runtime(\..*)?", RUNTIME),
    (r"services\.(motor|odometry|localization)\.core", CORE),
    (r"services\.localization\.(amcl|likelihood)", CORE),
    (r"services\.mapping\.(occupancy|matcher|builder|from_recording)", CORE),
    (r"services\.motor\.state", CORE),
    (r"services\.motor\.(sim_pose|speed_limiter|wheel_velocity|collision|monitor)", CORE),
    (r"services\.drive\.(scenarios|path_following|outcome|goals|goal_approach|goal_file|options)", CORE),
    (r"services\.clock\.(sim_time|lockstep|observation)", CORE),
    (r"services\.planar", CORE),
    (r"services\.fleet\.(description|summary)", CORE),
    (r"services\.calibration\.(umbmark|measured|benchmark|settings)", CORE),
    (r"services\.goto\.core", CORE),
    (r"services\.extension\.driving", CORE),
    (r"services\.navigation\.(grid|map_file|rasterize|traversal|costmap|planner|tracker|navigator)", CORE),
    (r"services\.body\.geometry", CORE),
    (
        r"sim_bridge\.(simulator|robot|world|building|ray_world|sensors|latency|display|torque_policy|progress|status|"
        + r"kinematic_model|kinematic_world|kinematic|engine)",
        CORE,
    ),
    (r"services\.ros2\.(core|wire|interfaces|urdf|graph|outputs|sensors|navigate|goal_book|tf_tree)", CORE),
    (r"services\.(motor|odometry|localization|drive|ros2)\.service", SHELL),
    (r"services\.drive\.(goal_shell|navigation_shell)", SHELL),
    (r"services\.localization\.amcl_shell", SHELL),
    (r"services\.ros2\.(action_server|action_calls|odometry_services|motor_services|node_entities)", SHELL),
    (r"sim_bridge\.(bridge|link|liveness|loops|handshakes)", SHELL),
    (r"services\.(service|interfaces)", SHELL_SUPPORT),
    (r"services\.clock\.sim_watch", SHELL_SUPPORT),
    (r"services\.extension\.(api|loader|hosting|drive_output)", SHELL_SUPPORT),
    (r"services\.(cli|launch|recording)(\..*)?", TOOL),
    (r"services\.security(\..*)?", TOOL),
    (
        r"(services|sim_bridge|services\.(motor|odometry|localization|drive|clock|ros2|fleet|calibration|body|goto|extension|navigation|mapping))",
        PACKAGE,
    ),
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


def _room(module: str) -> str:
    """The package a module sits in: the modules of one service's shell share it (``sim_bridge/``)."""
    return module.rpartition(".")[0]


def _broken_rule(module: str, layer: str, imported: str, imported_layer: str | None) -> str | None:
    project = PROJECT.fullmatch(imported) is not None
    if layer == BASE and project:
        return "the exit statuses and the exceptions import nothing of the project"
    if imported_layer == BASE:
        return None  # anything may import them
    if _is(imported, COMMAND_LINE) and not _is(module, COMMAND_LINE):
        return "nothing imports the command line (services/cli/) but itself"
    if (
        _is(imported, SIM_BRIDGE)
        and not _is(module, SIM_BRIDGE)
        and not any(_is(module, importer) for importer in SIM_BRIDGE_IMPORTERS)
    ):
        return "only the launcher (services/launch/) and the command line import the simulator bridge (sim_bridge/)"
    if layer == SCHEMAS and project and imported_layer != SCHEMAS:
        return "the schemas import only msgspec and the standard library"
    if layer == CONFIG and project and imported_layer not in (SCHEMAS, CONFIG):
        return "the configuration imports only the schemas and the project's exceptions"
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
        if imported_layer == SHELL and _room(imported) != _room(module):
            return "no shell imports another"
        if imported_layer == TOOL:
            return "a shell never imports a tool"
    return None


def import_cycles(imports: Mapping[str, set[str]]) -> list[list[str]]:
    """Every set of project modules that import each other, directly or through others (a
    strongly connected component of the import graph with more than one module), each sorted."""
    graph = {
        module: {imported for imported in imported_modules if imported in imports and imported != module}
        for module, imported_modules in imports.items()
    }
    index: dict[str, int] = {}
    lowest: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(module: str) -> None:  # Tarjan's algorithm
        index[module] = lowest[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for imported in sorted(graph[module]):
            if imported not in index:
                visit(imported)
                lowest[module] = min(lowest[module], lowest[imported])
            elif imported in on_stack:
                lowest[module] = min(lowest[module], index[imported])
        if lowest[module] == index[module]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == module:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(cycles)


def rooms_mixing_tools(layers: Mapping[str, str]) -> list[str]:
    """Every room (a subpackage of ``services/``, or ``sim_bridge/``) that holds a tool beside a core
    or a shell: a shell or a core that imports from it would import from a room that sits above
    the command line. ``services/`` itself holds the few pieces every layer shares."""
    rooms: dict[str, set[str]] = {}
    for module, layer in layers.items():
        room = module.rpartition(".")[0]
        if room != "services":
            rooms.setdefault(room, set()).add(layer)
    mixed = []
    for room, room_layers in sorted(rooms.items()):
        below = sorted(room_layers & {CORE, SHELL, SHELL_SUPPORT})
        if TOOL in room_layers and below:
            mixed.append(f"{room} holds tools beside {' and '.join(below)} modules")
    return mixed


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
            # `from services.recording import record`: the submodule is what is imported
            submodules = [f"{base}.{alias.name}" for alias in node.names if _exists(f"{base}.{alias.name}")]
            # A module taking siblings through its own package (`from services.config import sections` in
            # services/config/description.py) imports them, not the package, whose import is under way.
            if not (module.startswith(f"{base}.") and len(submodules) == len(node.names)):
                yield base
            yield from submodules


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


def test_a_module_taking_its_siblings_through_its_package_does_not_import_the_package():
    package = ROOT / "services" / "config"
    imports = set(_imports(package / "description.py", "services.config.description"))
    assert {"services.config.sections", "services.config.run_sections"} <= imports
    assert "services.config" not in imports


def test_every_module_of_the_project_has_a_layer():
    imports = project_imports()
    assert {"services.motor.core", "services.motor.service", "sim_bridge.bridge", "services.launch.up"} <= set(imports)
    assert [module for module in imports if layer_of(module) is None] == []


def test_no_modules_of_the_project_import_each_other():
    assert import_cycles(project_imports()) == []


def test_no_room_holds_a_tool_beside_a_core_or_a_shell():
    layers = {module: layer_of(module) or "" for module in project_imports() if layer_of(module) != PACKAGE}
    assert rooms_mixing_tools(layers) == []


def test_a_circle_of_imports_is_found_however_long():
    imports = {
        "services.launch.up": {"services.launch.fleet", "services.launch.run"},
        "services.launch.fleet": {"services.launch.run", "services.recording.report"},
        "services.launch.run": {"services.launch.up"},
        "services.recording.report": {"services.motor.core"},
        "services.motor.core": set(),
    }
    assert import_cycles(imports) == [["services.launch.fleet", "services.launch.run", "services.launch.up"]]
    imports["services.launch.run"] = set()
    assert import_cycles(imports) == []


def test_a_room_holding_a_launcher_beside_its_cores_is_found():
    layers = {"services.fleet.description": CORE, "services.fleet.summary": CORE, "services.fleet.launch": TOOL}
    assert rooms_mixing_tools(layers) == ["services.fleet holds tools beside core modules"]
    assert rooms_mixing_tools({"services.recording.record": TOOL, "services.motor.core": CORE}) == []


def test_each_service_room_holds_its_shell_and_its_core():
    for service, cores in {
        "motor": ("core", "state", "sim_pose", "speed_limiter", "wheel_velocity", "collision", "monitor"),
        "odometry": ("core",),
        "localization": ("core", "amcl", "likelihood"),
        "drive": ("scenarios", "path_following", "outcome", "goals", "goal_file"),
    }.items():
        room = ROOT / "services" / service
        assert (room / "service.py").is_file(), service
        for core in cores:
            assert layer_of(f"services.{service}.{core}") == CORE
            assert (room / f"{core}.py").is_file(), (service, core)


def test_the_services_top_level_holds_subpackages_and_a_handful_of_shared_modules():
    modules = sorted(path.name for path in (ROOT / "services").glob("*.py"))
    assert modules == ["__init__.py", "errors.py", "exits.py", "interfaces.py", "planar.py", "service.py"]


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
        ("services.drive.service", "services.launch.up", "a shell never imports a tool"),
        (
            "services.recording.replay",
            "services.cli.tools",
            "nothing imports the command line (services/cli/) but itself",
        ),
        ("services.launch.up", "services.cli.main", "nothing imports the command line (services/cli/) but itself"),
        ("services.runtime.node", "services.motor.core", "the runtime imports no service, core or tool"),
        ("schemas.keys", "services.config", "the schemas import only msgspec and the standard library"),
        ("services.exits", "services.config", "the exit statuses and the exceptions import nothing of the project"),
        ("services.errors", "schemas.codec", "the exit statuses and the exceptions import nothing of the project"),
        (
            "services.config.sections",
            "services.runtime.node",
            "the configuration imports only the schemas and the project's exceptions",
        ),
        (
            "services.recording.scene",
            "sim_bridge.robot",
            "only the launcher (services/launch/) and the command line import the simulator bridge (sim_bridge/)",
        ),
        (
            "services.ros2.service",
            "sim_bridge.bridge",
            "only the launcher (services/launch/) and the command line import the simulator bridge (sim_bridge/)",
        ),
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
        "services.config.loading": {"services.config.description", "services.errors", "schemas.keys"},
        "services.runtime.session": {"services.errors", "services.config"},
        "sim_bridge.robot": {"services.body.geometry"},
        "services.recording.scene": {"services.body.geometry"},
        "services.launch.up": {"sim_bridge.world", "sim_bridge.display"},
        "services.cli.main": {"sim_bridge.bridge"},
        "sim_bridge.bridge": {"sim_bridge.link", "sim_bridge.loops", "sim_bridge.handshakes"},
        "sim_bridge.link": {"sim_bridge.torque_policy", "sim_bridge.liveness", "zenoh"},
        "services.drive.outcome": {"services.exits"},
        "schemas.keys": {"services.errors"},
        "services.exits": {"enum"},
    }
    assert violations(allowed) == []


def test_an_unplaced_module_is_named():
    assert violations({"services.newcomer": set()}) == [
        "services.newcomer has no layer: place it in tests/test_layers.py and docs/architecture.md"
    ]
