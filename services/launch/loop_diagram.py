"""The loop diagram of docs/architecture.md section 2, made from the services' declarations
(services/interfaces.py): ``python -m services.launch.loop_diagram`` writes it there, between its
markers; tests/test_interfaces.py checks that the docs hold what this makes.

An edge is a key one service publishes and another subscribes (dotted: a participant's output, which
the simulator takes only for its tick barrier), or a query (dotted) of a key another serves; a
status query is not drawn (every service answers one). The description is the defaults'
(``localization.mode = "stub"``).
"""

from __future__ import annotations

from pathlib import Path

from schemas.interface import Interface
from schemas.keys import Keys, Service
from services import interfaces
from services.config import Config
from services.drive.service import COMMAND as DRIVE
from services.localization.service import COMMAND as LOCALIZATION
from services.motor.service import COMMAND as MOTOR
from services.odometry.service import COMMAND as ODOMETRY
from services.service import ServiceCommand
from sim_bridge.bridge import COMMAND as SIM

BEGIN = "<!-- the loop diagram: made by `python -m services.launch.loop_diagram` from services/interfaces.py -->"
END = "<!-- end of the loop diagram -->"
ARCHITECTURE = Path(__file__).resolve().parents[2] / "docs" / "architecture.md"
SHELLS: tuple[ServiceCommand, ...] = (SIM, MOTOR, ODOMETRY, LOCALIZATION, DRIVE)
"""The loop's services, each with the module of its shell (named in its box)."""


def _shell_file(command: ServiceCommand) -> str:
    return command.factory.__module__.replace(".", "/") + ".py"


def render() -> str:
    """The mermaid flowchart of the closed loop's declared interfaces, fenced (robot ``rh0``, the defaults)."""
    keys, config = Keys(), Config()
    declared = {str(c.service): interfaces.declared(Service(c.service), keys, config) for c in SHELLS}
    relative = len(keys.prefix) + 1
    lines = ["```mermaid", "flowchart LR"]
    lines += [f'    {command.service}["{command.service}<br/>{_shell_file(command)}"]' for command in SHELLS]
    lines.append("")
    outputs = {i.participates.output for i in declared.values() if i.participates is not None}
    for publisher, interface in declared.items():
        for key in interface.publishes:
            for subscriber, other in declared.items():
                if subscriber == publisher or key not in other.subscribes:
                    continue
                barrier = other.follows_participants and key in outputs
                arrow, note = ("-.->", " (tick barrier)") if barrier else ("-->", "")
                lines.append(f'    {publisher} {arrow}|"{key[relative:]}{note}"| {subscriber}')
    for caller, interface in declared.items():
        for key in interface.queries:
            server = _server(declared, keys, key)
            if server is not None:
                lines.append(f'    {caller} -.->|"query {key[relative:]}"| {server}')
    lines.append("```")
    return "\n".join(lines) + "\n"


def _server(declared: dict[str, Interface], keys: Keys, key: str) -> str | None:
    """Which service serves ``key`` (a queryable, or a latched key's last message); None for a status."""
    for name, interface in declared.items():
        if key in interface.serves or key in interface.latched_published(keys):
            return name
    return None


def replaced(document: str, diagram: str) -> str:
    """``document`` with what stands between :data:`BEGIN` and :data:`END` replaced by ``diagram``."""
    head, begin, rest = document.partition(BEGIN)
    _, end, tail = rest.partition(END)
    if not begin or not end:
        raise ValueError(f"the markers {BEGIN!r} and {END!r} are not both there")
    return f"{head}{BEGIN}\n{diagram}{END}{tail}"


if __name__ == "__main__":
    ARCHITECTURE.write_text(replaced(ARCHITECTURE.read_text(), render()))
