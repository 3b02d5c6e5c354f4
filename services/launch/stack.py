"""A run of ``invent up`` as a typed description, a *stack* (``invent up --print-stack``, ``--stack
FILE.toml``; docs/stack.md): what drives the robots (a scenario, goals or teleop), how the services
are placed in processes (separate or composed), what the run records and who watches it. Where
flags exclude each other, the stack has one variant per choice (a tagged table, its ``kind``), so
a stack cannot say what the flags refuse: no goals with a loop, no ``split`` of a composed run, no
bag without the bridge, no TLS without ``secure``. Pure: no zenoh.

A stack becomes the :class:`~services.launch.plan.UpPlan` the flags would give
(:func:`plan_from_stack`), and a plan its stack (:func:`stack_from_plan`): the two are one run."""

from __future__ import annotations

import tomllib
import typing
from pathlib import Path

import msgspec

from services.config import ConfigError, SimMode
from services.config.writing import toml_value
from services.launch.plan import DEFAULT_SCENARIO, DEPLOYMENT_SETTINGS, Connection, Description, UpPlan
from services.launch.restart import DEFAULT_FIRST_DELAY_S, DEFAULT_LIMIT, RestartPlan, RestartPolicy, parse_restarts
from services.runtime.logs import LOG_LEVELS


class _Table(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True, kw_only=True):
    """A table of the stack file: unknown keys refused, defaults left out when printed."""


class _Variant(_Table, frozen=True, tag_field="kind"):
    """One choice of a table whose ``kind`` says which."""


class RobotDescription(_Table, frozen=True):
    """The robot description, as ``--robot``, ``--config``, ``--set`` and ``--rt`` give it."""

    robot: str | None = None
    config: str | None = None
    settings: list[str] = msgspec.field(default_factory=list)
    """Each ``SECTION.KEY=VALUE``, in order (the later value of a key wins), given to every service."""
    rt: bool = False


class Network(_Table, frozen=True):
    """How the run's processes reach zenoh: ``--connect``, ``--listen``, ``--zenoh-config``, ``--log-level``."""

    connect: list[str] = msgspec.field(default_factory=list)
    listen: list[str] = msgspec.field(default_factory=list)
    zenoh_config: str | None = None
    log_level: str = "info"


class Scenario(_Variant, frozen=True, tag="scenario"):
    """Each drive runs a scenario (``--scenario``; a fleet robot's own, or its goal file, where it names one)."""

    name: str | None = None
    """Built-in or TOML file; none: the default (``square``), and a fleet robot's own."""
    loop: bool = False
    """Over and over until Ctrl-C (``--loop``)."""


class Goals(_Variant, frozen=True, tag="goals"):
    """Each drive takes goals (``--goals``), or those of a goal file (``--goal-file``)."""

    file: str | None = None


class Teleop(_Variant, frozen=True, tag="teleop"):
    """No drive: the robots follow ROS 2's ``/cmd_vel`` (``--teleop``; needs the bridge)."""


Commander = Scenario | Goals | Teleop


class Separate(_Variant, frozen=True, tag="separate"):
    """A process per service (the default)."""

    split: bool = False
    """A realtime run's sim and motor as two processes, not one ``invent control`` (``--split``)."""


class Composed(_Variant, frozen=True, tag="composed"):
    """The services in ``invent up``'s own process (``--composed``)."""

    workers: int | None = None
    """A fleet's robots over this many processes (``--workers``)."""
    intra_process: bool = True
    """Messages handed over as they are between the composed services (``--no-intra-process``: false)."""


Processes = Separate | Composed


class Recording(_Variant, frozen=True, tag="record"):
    """``run.mcap`` and the report (the default)."""

    report: str | None = None
    """Their directory (``--report``; none: ``runs/<timestamp>/``)."""


class NoRecording(_Variant, frozen=True, tag="none"):
    """Nothing recorded, no report (``--no-record``)."""


RecordingChoice = Recording | NoRecording


class Ros2Bridge(_Table, frozen=True):
    """``invent ros2`` beside the loop (``--ros2``)."""

    record: bool = False
    """Its topics in a rosbag2 bag beside ``run.mcap`` (``--record-ros2``)."""


class Secure(_Table, frozen=True):
    """Authentication and access control on the run's router (``--secure``)."""

    tls: bool = False


class Observers(_Table, frozen=True):
    view: int | None = None
    """The port of the live Foxglove view (``--view``)."""
    gui: bool = False
    """PyBullet's window (``--gui``)."""


class Restarts(_Table, frozen=True):
    """The restart policy (``--restart``, ``--restart-limit``, ``--restart-backoff``)."""

    policies: list[str] = msgspec.field(default_factory=list)
    """Each ``POLICY`` (every service) or ``SERVICE=POLICY``, as ``--restart`` takes it."""
    limit: int = DEFAULT_LIMIT
    backoff: float = DEFAULT_FIRST_DELAY_S


class Stack(_Table, frozen=True):
    """One run of ``invent up``. See the module docstring."""

    fleet: str | None = None
    mode: SimMode | None = None
    """Lockstep or realtime; none: the description's (``--goals`` and ``--teleop``: realtime)."""
    strict: bool = False
    services: list[str] = msgspec.field(default_factory=list)
    """Services of one's own beside the loop, ``FILE.py:NAME`` (``--with``)."""
    sim_set: list[str] = msgspec.field(default_factory=list)
    """The simulated body's own settings (``--sim-set``)."""
    description: RobotDescription = msgspec.field(default_factory=RobotDescription)
    network: Network = msgspec.field(default_factory=Network)
    commander: Commander = msgspec.field(default_factory=Scenario)
    processes: Processes = msgspec.field(default_factory=Separate)
    recording: RecordingChoice = msgspec.field(default_factory=Recording)
    ros2: Ros2Bridge | None = None
    security: Secure | None = None
    observers: Observers = msgspec.field(default_factory=Observers)
    restarts: Restarts = msgspec.field(default_factory=Restarts)


def plan_from_stack(stack: Stack) -> UpPlan:
    """The run ``stack`` describes; ConfigError naming a restart policy that is none."""
    commander, processes, recording = stack.commander, stack.processes, stack.recording
    described = stack.description
    deployment = isinstance(commander, Goals) or isinstance(commander, Scenario) and commander.loop
    settings = (*(DEPLOYMENT_SETTINGS if deployment else ()), *described.settings)
    default, by_service = parse_restarts(stack.restarts.policies)
    if stack.network.log_level not in LOG_LEVELS:
        raise ConfigError(f"network.log_level {stack.network.log_level!r}: one of {', '.join(LOG_LEVELS)}")
    return UpPlan(
        connection=Connection(
            tuple(stack.network.connect),
            tuple(stack.network.listen),
            stack.network.zenoh_config,
            stack.network.log_level,
        ),
        description=Description(described.robot, described.config, settings, described.rt),
        scenario=commander.name or DEFAULT_SCENARIO if isinstance(commander, Scenario) else DEFAULT_SCENARIO,
        scenario_given=isinstance(commander, Scenario) and commander.name is not None,
        fleet=stack.fleet,
        mode=stack.mode,
        report=Path(recording.report) if isinstance(recording, Recording) and recording.report else None,
        no_record=isinstance(recording, NoRecording),
        gui=stack.observers.gui,
        view=stack.observers.view,
        strict=stack.strict,
        loop=isinstance(commander, Scenario) and commander.loop,
        secure=stack.security is not None,
        tls=stack.security is not None and stack.security.tls,
        ros2=stack.ros2 is not None,
        record_ros2=stack.ros2 is not None and stack.ros2.record,
        teleop=isinstance(commander, Teleop),
        goals=isinstance(commander, Goals) and commander.file is None,
        goal_file=commander.file if isinstance(commander, Goals) else None,
        composed=isinstance(processes, Composed),
        split=isinstance(processes, Separate) and processes.split,
        workers=processes.workers if isinstance(processes, Composed) else None,
        intra_process=not isinstance(processes, Composed) or processes.intra_process,
        with_services=tuple(stack.services),
        restarts=RestartPlan(default, by_service, stack.restarts.limit, stack.restarts.backoff),
        sim_set=tuple(stack.sim_set),
    )


def stack_from_plan(plan: UpPlan) -> Stack:
    """The stack of ``plan``; ConfigError naming the flags a stack cannot hold together (each is
    refused by ``invent up`` too, or has no effect there)."""
    _refuse_what_no_stack_holds(plan)
    commander: Commander
    if plan.teleop:
        commander = Teleop()
    elif plan.goal_mode:
        commander = Goals(file=plan.goal_file)
    else:
        commander = Scenario(name=plan.scenario if plan.scenario_given else None, loop=plan.loop)
    processes: Processes = (
        Composed(workers=plan.workers, intra_process=plan.intra_process)
        if plan.composed
        else Separate(split=plan.split)
    )
    restarts = plan.restarts
    default = [str(restarts.default)] if restarts.default is not RestartPolicy.NEVER else []
    policies = [*default, *(f"{service}={policy}" for service, policy in restarts.by_service.items())]
    description, connection = plan.description, plan.connection
    settings = list(description.settings)
    if (plan.goal_mode or plan.loop) and tuple(settings[: len(DEPLOYMENT_SETTINGS)]) == DEPLOYMENT_SETTINGS:
        del settings[: len(DEPLOYMENT_SETTINGS)]  # the run's kind says them (plan_from_stack)
    return Stack(
        fleet=plan.fleet,
        mode=plan.mode,
        strict=plan.strict,
        services=list(plan.with_services),
        sim_set=list(plan.sim_set),
        description=RobotDescription(
            robot=description.robot, config=description.config, settings=settings, rt=description.rt
        ),
        network=Network(
            connect=list(connection.connect),
            listen=list(connection.listen),
            zenoh_config=connection.zenoh_config,
            log_level=connection.log_level,
        ),
        commander=commander,
        processes=processes,
        recording=NoRecording()
        if plan.no_record
        else Recording(report=None if plan.report is None else str(plan.report)),
        ros2=Ros2Bridge(record=plan.record_ros2) if plan.ros2 else None,
        security=Secure(tls=plan.tls) if plan.secure else None,
        observers=Observers(view=plan.view, gui=plan.gui),
        restarts=Restarts(policies=policies, limit=restarts.limit, backoff=restarts.first_delay_s),
    )


def _refuse_what_no_stack_holds(plan: UpPlan) -> None:
    held_apart = {
        "--teleop with --loop": plan.teleop and plan.loop,
        "--teleop with --scenario": plan.teleop and plan.scenario_given,
        "--record-ros2 without --ros2": plan.record_ros2 and not plan.ros2,
        "--tls without --secure": plan.tls and not plan.secure,
        "--workers without --composed": plan.workers is not None and not plan.composed,
        "--no-intra-process without --composed": not plan.intra_process and not plan.composed,
        "--split with --composed": plan.split and plan.composed,
        "--report with --no-record": plan.report is not None and plan.no_record,
    }
    refused = [flags for flags, given in held_apart.items() if given]
    if refused:
        raise ConfigError(f"{', '.join(refused)}: no stack holds these together (docs/stack.md)")


def read_stack(path: str) -> Stack:
    """The stack of a TOML file; ConfigError (exit 2) naming the file and the field that is wrong."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except OSError as error:
        raise ConfigError(f"--stack {path}: {error.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(f"--stack {path}: not TOML: {error}") from None
    try:
        return msgspec.convert(data, Stack)
    except msgspec.ValidationError as error:
        raise ConfigError(f"--stack {path}: {_named(error)}") from None


KINDS: dict[str, tuple[type[_Variant], ...]] = {
    "commander": typing.get_args(Commander),
    "processes": typing.get_args(Processes),
    "recording": typing.get_args(RecordingChoice),
}
"""The tables with variants, and their variants."""


def _named(error: msgspec.ValidationError) -> str:
    """msgspec's message with its JSON path (``$.commander.kind``) as the TOML's key
    (``commander.kind``), and a variant's choices where its ``kind`` is wrong."""
    text = str(error)
    message, found, path = text.rpartition(" - at `")
    if not found:
        return text
    key = path.rstrip("`").removeprefix("$").lstrip(".") or "the file"
    table, _, field = key.partition(".")
    if table in KINDS and (field == "kind" or "`kind`" in message):
        message += f" (kind is one of {', '.join(str(variant.__struct_config__.tag) for variant in KINDS[table])})"
    return f"{key}: {message}"


def stack_toml(stack: Stack) -> str:
    """TOML text of ``stack`` that :func:`read_stack` reads back as the same stack: its own keys,
    then a table each, defaults left out (a table with none left is left out but a variant's ``kind``)."""
    tree = msgspec.to_builtins(stack)
    lines = ["# invent up --stack FILE: one run of the stack (docs/stack.md)"]
    lines += [f"{key} = {toml_value(value)}" for key, value in tree.items() if not isinstance(value, dict)]
    for name, table in tree.items():
        if isinstance(table, dict) and (table or name in ("ros2", "security")):
            lines += ["", f"[{name}]", *(f"{key} = {toml_value(value)}" for key, value in table.items())]
    return "\n".join(lines) + "\n"
