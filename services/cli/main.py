"""``invent``: the command line of invent-zenoh. ``invent --help`` lists every subcommand."""

from __future__ import annotations

import argparse
import datetime
import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import msgspec
import zenoh

from schemas.keys import DEFAULT_ROBOT, Keys, Service
from services.cli import tools
from services.config import Config, ConfigError, RecordRate, TfLayout, load_config, parse_override
from services.errors import SessionFailed
from services.exits import ExitStatus
from services.fleet.description import fleet_configs, load_fleet
from services.launch import calibrate, fleet, ros2_run, up, worker
from services.recording import record, replay, ros2_record, rosbag, view
from services.recording.mcap_files import read_run, replay_schedule, write_run_report
from services.recording.report import summary
from services.ros2.graph import bridge_graph
from services.runtime.logs import configure_logging
from services.runtime.realtime import apply_realtime
from services.runtime.session import (
    DEFAULT_ENDPOINT,
    LOOPBACK_LISTEN,
    ZENOH_CONFIG_VARIABLE,
    open_session,
    session_config,
    stop_on_signals,
)
from services.service import (
    ServiceCommand,
    config_from_args,
    non_negative_float,
    overrides_from_args,
    port_number,
    positive_seconds,
    robot_name,
    run_service,
)

SERVICE_MODULES = (
    "sim_bridge.bridge",
    "services.motor.service",
    "services.odometry.service",
    "services.localization.service",
    "services.drive.service",
    "services.ros2.service",
)
"""Modules that each define ``COMMAND: ServiceCommand``; one ``invent <service>`` subcommand each."""


def service_commands() -> list[ServiceCommand]:
    return [importlib.import_module(name).COMMAND for name in SERVICE_MODULES]


def _connection_flags() -> argparse.ArgumentParser:
    flags = argparse.ArgumentParser(add_help=False)
    group = flags.add_argument_group("zenoh connection")
    group.add_argument(
        "--connect",
        metavar="EP",
        action="append",
        default=[],
        help=f"endpoint to connect to (repeatable; default {DEFAULT_ENDPOINT}, or $ZENOH_CONFIG)",
    )
    group.add_argument(
        "--listen",
        metavar="EP",
        action="append",
        default=[],
        help=f"endpoint to listen on as well (repeatable; a peer always listens on {LOOPBACK_LISTEN} and nothing "
        "else unless told, e.g. --listen tcp/0.0.0.0:0 to accept other machines)",
    )
    group.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help=f"zenoh configuration file replacing the default (e.g. a role's file from `invent secrets`; "
        f"default ${ZENOH_CONFIG_VARIABLE}); --connect/--listen still apply on top",
    )
    group.add_argument(
        "--log-level", default="info", choices=["debug", "info", "warning", "error"], help="log level (default info)"
    )
    return flags


def _service_flags() -> argparse.ArgumentParser:
    flags = argparse.ArgumentParser(add_help=False)
    group = flags.add_argument_group("robot description")
    group.add_argument(
        "--robot", metavar="NAME", help=f"robot name, the key prefix invent/NAME/ (default {DEFAULT_ROBOT})"
    )
    group.add_argument("--config", metavar="FILE", help="robot description TOML file (see docs/configuration.md)")
    group.add_argument(
        "--set",
        metavar="SECTION.KEY=VALUE",
        action="append",
        help="override one config value, e.g. --set motor.p_gain_l=3.0 (repeatable)",
    )
    return flags


def _rt_flags() -> argparse.ArgumentParser:
    flags = argparse.ArgumentParser(add_help=False)
    group = flags.add_argument_group("real time")
    group.add_argument(
        "--rt",
        action="store_true",
        help="real-time settings (the [rt] table, e.g. --set rt.priority=70): SCHED_FIFO, locked memory, "
        "the CPUs of rt.cpus, the garbage collector frozen after start-up; what the system refuses is said "
        "in one line and skipped (docs/realtime.md)",
    )
    return flags


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="invent",
        description="invent-zenoh: a differential-drive robot stack on zenoh (motor, odometry, "
        "localization, drive and a PyBullet simulator, each a service).",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    connection, service, rt = _connection_flags(), _service_flags(), _rt_flags()

    router = commands.add_parser(
        "router",
        parents=[connection, rt],
        help="run a zenoh router in Python (no zenohd needed)",
        description=f"A zenoh router; services connect to it. Default listen: {DEFAULT_ENDPOINT}. "
        "--config FILE (or $ZENOH_CONFIG) takes a zenoh router configuration, such as the router.json5 of "
        "`invent secrets` (authentication and access control).",
    )
    router.add_argument("--config", dest="zenoh_config", metavar="FILE", help="zenoh router configuration file")
    router.add_argument(
        "--set",
        metavar="rt.KEY=VALUE",
        action="append",
        help="a real-time setting of the robot description's [rt] table, e.g. --set rt.priority=70 (repeatable)",
    )
    router.set_defaults(handler=_router)

    secrets_parser = commands.add_parser(
        "secrets",
        help="write a secure deployment's credentials, router and per-role zenoh configurations",
        description="Write fresh credentials for every role (sim, motor, odometry, localization, drive, ros2, "
        "ros_node, operator, observer) into DIR: router.json5 (usrpwd authentication and access control, default "
        "deny), dictionary.txt, and ROLE.json5, a complete client configuration per role (mode client, the "
        "router's endpoint, that role's user and password), all mode 0600. Start the router with "
        "`invent router --config DIR/router.json5` and each service with `--zenoh-config DIR/ROLE.json5`.",
    )
    secrets_parser.add_argument("directory", metavar="DIR", help="where to write the files (created 0700)")
    secrets_parser.add_argument(
        "--robot", default=DEFAULT_ROBOT, metavar="NAME", help=f"the robot the rules name (default {DEFAULT_ROBOT})"
    )
    secrets_parser.add_argument(
        "--robots",
        type=tools.robot_names,
        default=(),
        metavar="R1,R2,...",
        help="a fleet's credentials, in place of --robot's: per robot, one user and ROBOT-ROLE.json5 for each of "
        "motor, odometry, localization, drive and ros2 (that robot's keys only; its bridge in the ROS namespace "
        "/ROBOT under --ros-namespace); one sim, operator, observer and ros_node for the whole fleet",
    )
    secrets_parser.add_argument(
        "--endpoint", default=DEFAULT_ENDPOINT, metavar="EP", help=f"where clients connect (default {DEFAULT_ENDPOINT})"
    )
    secrets_parser.add_argument(
        "--router-listen",
        action="append",
        default=[],
        metavar="EP",
        help="where the router listens (repeatable; default the endpoint; e.g. tcp/[::]:7447 in a container)",
    )
    secrets_parser.add_argument(
        "--tls", action="store_true", help="tls/ endpoints, a local CA and a router certificate in DIR/tls"
    )
    secrets_parser.add_argument(
        "--tls-name",
        action="append",
        default=[],
        metavar="NAME",
        help="another host name or address the router's certificate is valid for (repeatable; "
        "localhost and 127.0.0.1 always are)",
    )
    secrets_parser.add_argument(
        "--seen-as",
        metavar="PATH",
        help="the path the router and services see DIR at, when it is mounted elsewhere (a container's)",
    )
    secrets_parser.add_argument(
        "--router-base",
        metavar="FILE",
        help="a zenoh router configuration whose plugins (REST, storages) the router's file keeps, "
        "e.g. docker/zenohd.json5",
    )
    secrets_parser.add_argument(
        "--ros-namespace",
        metavar="NS",
        help="the ROS namespace of the ROS 2 bridge the ros2 role is granted (default none; the domain is "
        "$ROS_DOMAIN_ID, default 0); the ros_node role may do anything in that domain",
    )
    secrets_parser.add_argument(
        "--ros-tf",
        choices=list(TfLayout),
        help="the TF layout of the bridges the ros2 roles are granted (ros2.tf; default namespaced: each robot's "
        "tf in its namespace; prefixed: every robot's bridge may put on the shared /tf and /tf_static)",
    )
    secrets_parser.set_defaults(handler=_secrets, log_level="info")

    echo = commands.add_parser(
        "echo",
        parents=[connection],
        help="print samples as JSON lines, decoded with their key's schema",
        description="Subscribe to KEYEXPR and print one JSON line per sample: its key and its payload "
        "decoded with the schema that key carries (raw text for unknown keys).",
    )
    echo.add_argument("keyexpr", metavar="KEYEXPR", help="zenoh key expression, e.g. 'invent/rh0/**'")
    echo.add_argument("--count", type=int, metavar="N", help="exit after N samples")
    echo.set_defaults(handler=_echo)

    call = commands.add_parser(
        "call",
        parents=[connection],
        help="query a key (a Motor method, a status) and print the replies",
        description="Send a query to KEY with an optional JSON payload and print each reply as JSON. "
        "Exits 1 on an error reply or when nothing answers. Target velocities are not queries: "
        "drive/target_velocity is data the motor takes by its stamp, refusing as stale a target stamped "
        "before the simulation time minus motor.command_timeout (a target stamped 0.0 once the simulation is "
        "0.5 s in); send one with `invent drive --twist VX W`, which stamps with the newest simulation time.",
    )
    call.add_argument("key", metavar="KEY", help="e.g. invent/rh0/motor/gui/stop")
    call.add_argument("payload", metavar="JSON", nargs="?", help="e.g. '{\"p_gain_l\": 5, ...}'")
    call.add_argument("--timeout", type=float, default=2.0, metavar="S", help="seconds to wait (default 2)")
    call.set_defaults(handler=_call)

    status = commands.add_parser(
        "status",
        parents=[connection],
        help="list the services alive and their status",
        description="List the services alive (from their liveliness tokens) and print each one's status reply.",
    )
    status.add_argument("--robot", metavar="NAME", help="only this robot (default: every robot)")
    status.add_argument("--timeout", type=float, default=1.0, metavar="S", help="seconds to wait (default 1)")
    status.set_defaults(handler=_status)

    config = commands.add_parser(
        "config",
        parents=[service],
        help="print the resolved robot description (file + overrides) as JSON",
        description="Load the robot description as a service would (--config file, then --set overrides) "
        "and print it as JSON. Exits 2 naming the field when it is invalid.",
    )
    config.set_defaults(handler=_config, log_level="info")

    record = commands.add_parser(
        "record",
        parents=[connection, service],
        help="record keys into an MCAP file (open it in Foxglove, read it with the mcap CLI)",
        description="Record every sample of KEYEXPR (default invent/<robot>/**) into an MCAP file: one channel "
        "per key, JSON messages with their JSON schema, log_time the receive time, publish_time the message's "
        "tm; beside them the robot's Foxglove scene (transforms, poses, robot, obstacles, path, trails, wheel "
        "speeds) and the services' status every 0.5 s. Ctrl-C, SIGTERM or --duration end it with a valid, "
        "indexed file; a recorder killed with SIGKILL loses at most its last chunk (about 0.2 s of the loop).",
    )
    record.add_argument(
        "keyexprs", metavar="KEYEXPR", nargs="*", help="zenoh key expressions (default invent/<robot>/**)"
    )
    record.add_argument(
        "--output",
        "-o",
        metavar="PATH",
        help="file to write (default invent.mcap); with --ros2, the bag's new directory (default "
        "rosbag2_<date>-<time>, as `ros2 bag record` names one)",
    )
    record.add_argument("--duration", type=positive_seconds, metavar="S", help="stop after S seconds of wall time")
    record.add_argument(
        "--ros2",
        action="store_true",
        help="record the ROS 2 graph instead: every topic the robot's ROS 2 bridge publishes (of each robot with "
        "--fleet), as rmw_zenoh carries it, into a rosbag2 bag with MCAP storage (metadata.yaml, CDR, ros2msg "
        "schemas, ROS's type names and hashes), each message at the simulation time it carries, /clock included; "
        "the bounds of [record] apply (split_size, split_duration, max_size, max_duration, min_free_disk). "
        "`ros2 bag info DIR`, `ros2 bag play DIR --clock` (docs/ros2.md, Bags)",
    )
    record.add_argument(
        "--fleet",
        metavar="FILE",
        help="with --ros2: the bridges of every robot of this fleet file, in their namespaces",
    )
    record.set_defaults(handler=_record)

    export = commands.add_parser(
        "export",
        parents=[service],
        help="turn a recording of a run (run.mcap) into a ROS 2 bag",
        description="Replay a recording of `invent up` (its run.mcap, and the files it was split into) through the "
        "ROS 2 bridge's own mapping (services/ros2/outputs.py) and write what the bridge would have published, "
        "/clock, odom, tf, tf_static, joint_states and robot_description of each robot, into a rosbag2 bag with "
        "MCAP storage, each message at the simulation time it carries. The messages come at the recording's "
        "observed steps: a run with --ros2 has the bridge's rates. --robot, --config and --set (or --fleet) must "
        "match the run's; the [record] bounds apply to the bag.",
    )
    export.add_argument("recording", metavar="RUN.mcap", help="the recording, e.g. runs/<timestamp>/run.mcap")
    export.add_argument(
        "--ros2", action="store_true", required=True, help="the format: a rosbag2 bag (MCAP storage), ROS 2 CDR"
    )
    export.add_argument("--output", "-o", metavar="DIR", required=True, help="the bag's new directory")
    export.add_argument(
        "--fleet",
        metavar="FILE",
        help="the fleet file of the run: each robot in its namespace, /clock from the first (needed for a "
        "recording of several robots)",
    )
    export.set_defaults(handler=_export, log_level="info")

    view_parser = commands.add_parser(
        "view",
        parents=[connection, service],
        help="show the running robot live in Foxglove (a Foxglove WebSocket server)",
        description="Serve the robot's loop live to Foxglove over a Foxglove WebSocket server: every key of "
        "invent/<robot>/** as its own JSON channel (with its message type's JSON schema), the services' status "
        "every 0.5 s (the motor's state, the sim's torque counters), and the robot's Foxglove scene: /tf "
        "(world -> base_link, the ground truth), /odometry/pose and /localization/pose, /scene (the robot, the "
        "world's obstacles, the planned path, the trails) and /plot/wheel_speeds, the channels a recording holds. "
        "Open it in Foxglove: Open connection -> Foxglove WebSocket -> ws://HOST:PORT (the URL it prints), then "
        "Layouts -> Import from file -> docs/foxglove/layout.json for a 3D view, wheel speeds, torques and the "
        "motor's state. Runs until Ctrl-C or SIGTERM.",
    )
    view_parser.add_argument(
        "--port",
        type=port_number,
        default=view.DEFAULT_PORT,
        metavar="PORT",
        help=f"TCP port to serve on (default {view.DEFAULT_PORT}; 0: any free port, which it prints)",
    )
    view_parser.add_argument(
        "--host",
        default=view.DEFAULT_HOST,
        metavar="ADDR",
        help=f"address to serve on (default {view.DEFAULT_HOST}, this machine only; 0.0.0.0 for every "
        "interface, e.g. in a container)",
    )
    view_parser.add_argument(
        "--fleet",
        metavar="FILE",
        help="show every robot of this fleet file: each robot's frame <robot>/base_link, its poses and wheel "
        "speeds under /<robot>/..., its body, path and trails in /scene (docs/fleet.md)",
    )
    view_parser.set_defaults(handler=_view)

    report = commands.add_parser(
        "report",
        parents=[service],
        help="rebuild report.json and the plots from the recording of a run (run.mcap)",
        description="Read a recording of `invent up` (its run.mcap) and write report.json, trajectory.png and "
        "wheel_speeds.png, as `invent up` does at the end of a run, into --output-dir (default: the "
        "recording's directory). --robot and --config must match the run's.",
    )
    report.add_argument("recording", metavar="FILE.mcap", help="the recording, e.g. runs/<timestamp>/run.mcap")
    report.add_argument("--output-dir", metavar="DIR", help="where to write (default: beside the recording)")
    report.set_defaults(handler=_report, log_level="info")

    replay_parser = commands.add_parser(
        "replay",
        parents=[connection],
        help="publish a recording's samples again, e.g. into a changed odometry",
        description="Publish the samples of a recording (`invent record`, or the run.mcap of `invent up`) again, "
        "in simulation-time order, so a changed odometry, localization or drive runs on recorded inputs. "
        "--rate X paces them at X times the recorded simulation time; --rate 0 sends them as fast as the "
        "services that take every sample of those keys take them (read from their status), losing none. "
        "Exits 0 once those services have taken every sample, 1 if one stops taking them.",
    )
    replay_parser.add_argument("recording", metavar="FILE.mcap", help="the recording")
    replay_parser.add_argument(
        "--keys",
        metavar="SUFFIX",
        nargs="+",
        default=[],
        help="keys relative to the robot, e.g. motor/wheel_angles localization/pose (default: every data key "
        "recorded but up/run)",
    )
    replay_parser.add_argument(
        "--rate", type=non_negative_float, default=1.0, metavar="X", help="time scale (default 1; 0: consumers' pace)"
    )
    replay_parser.add_argument(
        "--robot",
        type=robot_name,
        metavar="NAME",
        help="publish under invent/NAME/ (default: the robot the recording is of)",
    )
    replay_parser.set_defaults(handler=_replay)

    up_parser = commands.add_parser(
        "up",
        parents=[connection, service, rt],
        help="run the whole loop (router, sim, motor, odometry, localization, drive) and write a report",
        description="Start every service as its own process in this terminal, drive a scenario, then stop "
        "everything and write a run report (report.json, trajectory.png, wheel_speeds.png). "
        f"--listen sets where its router listens (default {DEFAULT_ENDPOINT}); --connect joins an existing router "
        "instead. Ctrl-C stops everything.",
    )
    up.add_arguments(up_parser)
    up_parser.set_defaults(handler=_up)

    calibrate_parser = commands.add_parser(
        "calibrate",
        help="calibrate the odometry: UMBmark, in the simulator or from return positions measured by hand",
        description="Calibrate the robot's odometry. The one method: umbmark (`invent calibrate umbmark --help`).",
    )
    methods = calibrate_parser.add_subparsers(dest="method", required=True, metavar="METHOD")
    umbmark = methods.add_parser(
        "umbmark",
        parents=[service],
        help="UMBmark: drive a square both ways on odometry alone, correct the wheel radii and the wheelbase",
        description="UMBmark (Borenstein and Feng 1996): drive a square of side --side clockwise and "
        "counter-clockwise --runs times each on odometry alone, take where the robot really stops, and compute the "
        "systematic errors Ed (the ratio of the wheel diameters) and Eb (the wheelbase's) and the corrected "
        "odometry.left_radius_scale, right_radius_scale and axle_scale (used by the odometry and by the motor's "
        "wheel-speed conversion alike). In the simulator (the default) the loop runs composed in lockstep with no "
        "localization, the simulated body changed by --sim-set only, and the benchmark runs again with the "
        "corrections applied (E_max,syst before and after). --measured FILE takes return positions measured with a "
        "tape on the real robot instead. Writes report.json, umbmark.png (the paper's figure) and umbmark.mcap (the "
        "runs' paths, for Foxglove) into --report DIR, and with -o FILE the robot description with the corrections. "
        "Exit 0 done, 1 a run failed, 2 bad arguments or configuration, 130 Ctrl-C. See docs/odometry.md.",
    )
    calibrate.add_arguments(umbmark)
    umbmark.set_defaults(handler=_calibrate_umbmark)

    worker_parser = commands.add_parser(
        "worker",
        parents=[connection],
        help="(started by invent up --fleet --composed) compose the services it is sent on standard input",
        description="A worker of a composed fleet (docs/fleet.md): reads one JSON array per line on standard "
        'input, a service\'s name and the arguments `invent` takes (["rh1/motor", "motor", "--robot", "rh1"]), '
        "starts each composed in this process and says so on standard output; stops on SIGINT or end of input.",
    )
    worker_parser.add_argument(
        "--fleet",
        metavar="FILE",
        help="run the services (motor, odometry, localization, drive) of --robots of this fleet file, as "
        "invent up --fleet starts them: one process on a robot computer for its robots (docs/deploy.md)",
    )
    worker_parser.add_argument(
        "--robots", metavar="R1,R2,...", help="with --fleet: the robots whose services this process runs"
    )
    worker_parser.add_argument(
        "--no-intra-process", action="store_true", help="the services' messages through the zenoh session"
    )
    worker_parser.set_defaults(handler=_worker)

    for command in service_commands():
        sub = commands.add_parser(
            str(command.service),
            parents=[connection, service, rt],
            help=command.help,
            description=command.description,
        )
        command.add_arguments(sub)
        # invent up's own: where a service keeps what it publishes, for the run's recording, and how
        # many journals of the run share record.max_size
        sub.add_argument("--journal", metavar="DIR", help=argparse.SUPPRESS)
        sub.add_argument("--journal-share", type=int, default=1, help=argparse.SUPPRESS)
        sub.set_defaults(handler=_serve, service_command=command)
    return parser


def _session_config(args: argparse.Namespace, mode: str = "peer", timestamping: bool = False) -> zenoh.Config:
    return session_config(
        connect=args.connect, listen=args.listen, mode=mode, file=args.zenoh_config, timestamping=timestamping
    )


def _router(args: argparse.Namespace) -> int:
    overrides = {".".join(path): value for path, value in map(parse_override, args.set or ())}
    not_rt = [key for key in overrides if not key.startswith("rt.")]
    if not_rt:
        raise ConfigError(f"invent router --set {', '.join(not_rt)}: a router takes only the [rt] settings")
    apply_realtime(load_config(overrides={**overrides, "rt.enabled": args.rt or None}).rt, "invent router")
    config = _session_config(args, mode="router")
    stop = stop_on_signals()
    with open_session(config) as session:
        return tools.run_router(session, json.loads(config.get_json("listen/endpoints")), stop)


def _echo(args: argparse.Namespace) -> int:
    stop = stop_on_signals()
    with open_session(_session_config(args)) as session:
        return tools.run_echo(session, args.keyexpr, args.count, stop)


def _call(args: argparse.Namespace) -> int:
    with open_session(_session_config(args)) as session:
        return tools.run_call(session, args.key, args.payload, args.timeout)


def _status(args: argparse.Namespace) -> int:
    with open_session(_session_config(args)) as session:
        return tools.run_status(session, args.robot, args.timeout)


def _secrets(args: argparse.Namespace) -> int:
    return tools.run_secrets(
        Path(args.directory),
        Keys(args.robot),
        endpoint=args.endpoint,
        router_listen=args.router_listen,
        tls=args.tls,
        tls_names=args.tls_name,
        seen_as=Path(args.seen_as) if args.seen_as else None,
        router_base=args.router_base,
        ros=bridge_graph(load_config(overrides={"ros2.namespace": args.ros_namespace, "ros2.tf": args.ros_tf})),
        robots=args.robots,
    )


def _record(args: argparse.Namespace) -> int:
    config = config_from_args(None, args)
    if args.ros2:
        return _record_ros2(args, config)
    if args.fleet:
        raise ConfigError("--fleet: it is an option of --ros2 (the bridges of a fleet)")
    stop = stop_on_signals()
    with open_session(_session_config(args)) as session:
        return record.run_record(
            session,
            Keys(config.robot.name),
            args.keyexprs,
            Path(args.output or "invent.mcap"),
            config,
            stop,
            duration_s=args.duration,
        )


def _record_ros2(args: argparse.Namespace, config: Config) -> int:
    if args.keyexprs:
        raise ConfigError(f"--ros2 with {' '.join(args.keyexprs)}: a bag records the bridges' topics, not zenoh keys")
    configs = list(ros2_run.fleet_bridges(load_fleet(args.fleet), args).values()) if args.fleet else [config]
    bridges = [bridge_graph(robot) for robot in configs]
    output = Path(args.output or datetime.datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S"))
    if output.exists():
        raise ConfigError(f"--output {output}: it exists (a bag is written into a new directory)")
    stop = stop_on_signals()
    with open_session(_session_config(args)) as session:
        result = ros2_record.run_record_ros2(
            session,
            bridges,
            output,
            config.record,
            config.ros2.distro,
            config.input.stamp_horizon_ns,
            stop,
            duration_s=args.duration,
        )
    _say_bag(result)
    return 0


def _export(args: argparse.Namespace) -> int:
    path = Path(args.recording)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    output = Path(args.output)
    if output.exists():
        raise ConfigError(f"--output {output}: it exists (a bag is written into a new directory)")
    if args.fleet:
        configs = list(ros2_run.fleet_bridges(load_fleet(args.fleet), args).values())
    else:
        recorded = rosbag.robots_in(read_run(path).messages)
        if len(recorded) > 1:
            raise ConfigError(
                f"{path} holds the robots {', '.join(recorded)}: give the run's --fleet FILE (their namespaces "
                "and descriptions)"
            )
        if args.robot is None and recorded:
            args.robot = recorded[0]
        configs = [config_from_args(None, args)]
    result, refused = rosbag.export_run(
        path,
        output,
        [rosbag.ExportedRobot(config, bridge_graph(config)) for config in configs],
        configs[0].record,
    )
    for key, count in sorted(refused.items()):
        print(f"{count} recorded samples of {key} were bad input, not exported", file=sys.stderr)
    _say_bag(result)
    return 0


def _say_bag(result: rosbag.BagResult) -> None:
    counts = ", ".join(f"{topic} {count}" for topic, count in sorted(result.counts.items()))
    print(f"{result.path}: {result.messages} messages in {len(result.files)} file(s): {counts}")
    if result.stopped is not None:
        print(f"the bag stopped early: {result.stopped['reason']}")


def _view(args: argparse.Namespace) -> int:
    config = config_from_args(None, args)
    fleet = (
        tuple(fleet_configs(load_fleet(args.fleet), args.config, overrides_from_args(None, args)).values())
        if args.fleet
        else ()
    )
    stop = stop_on_signals()
    with open_session(_session_config(args)) as session:
        return view.run_view(
            session, Keys(config.robot.name), config, stop, host=args.host, port=args.port, fleet=fleet
        )


def _report(args: argparse.Namespace) -> int:
    path = Path(args.recording)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    report, report_path, plots = write_run_report(
        path, Path(args.output_dir) if args.output_dir else path.parent, config_from_args(None, args)
    )
    print(summary(report))
    print(f"report: {report_path}; plots: {', '.join(str(p) for p in plots)}")
    return 0


def _replay(args: argparse.Namespace) -> int:
    path = Path(args.recording)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    read = read_run(path)  # and the files it was split into, if any
    if not read.complete:
        print(f"{path} was cut short: replaying its whole chunks", file=sys.stderr)
    recorded_robot, schedule = replay_schedule(read.messages, replay.parse_topics(args.keys))
    keys = Keys(args.robot or recorded_robot)
    stop = stop_on_signals()
    with open_session(_session_config(args)) as session:
        return replay.run_replay(session, schedule, keys, args.rate, stop)


def _config(args: argparse.Namespace) -> int:
    print(json.dumps(msgspec.to_builtins(config_from_args(None, args)), indent=2))
    return 0


def _worker(args: argparse.Namespace) -> int:
    requests: list[list[str]] = []
    if bool(args.fleet) != bool(args.robots):
        raise ConfigError("invent worker: --fleet and --robots go together (or neither: up sends the services)")
    if args.fleet:
        fleet_file = load_fleet(args.fleet)
        names = [name.strip() for name in args.robots.split(",") if name.strip()]
        unknown = [name for name in names if name not in fleet_file.names]
        if unknown or not names:
            raise ConfigError(f"--robots {args.robots}: not robots of {args.fleet} ({', '.join(fleet_file.names)})")
        connection = [flag for endpoint in args.connect for flag in ("--connect", endpoint)]
        if args.zenoh_config:
            connection += ["--zenoh-config", args.zenoh_config]
        requests = worker.robot_requests(fleet_file, names, [*connection, "--log-level", args.log_level])
    stop = stop_on_signals()
    with open_session(_session_config(args)) as session:
        return worker.run_worker(
            session, build_parser(), stop, intra_process=not args.no_intra_process, requests=requests
        )


def _up(args: argparse.Namespace) -> int:
    if args.record_full_rate:  # for every service of the run, as the robot description's [record]
        args.set = [*(args.set or []), f"record.rate={RecordRate.EVERY_STEP}"]
    if args.tf:  # for every robot's bridge, as the robot description's [ros2]
        args.set = [*(args.set or []), f"ros2.tf={args.tf}"]
    if args.fleet:
        return fleet.run_fleet(args, build_parser())
    return up.run_up(args, config_from_args(None, args), build_parser())


def _calibrate_umbmark(args: argparse.Namespace) -> int:
    return calibrate.run_umbmark(args, build_parser())


def _serve(args: argparse.Namespace) -> int:
    command: ServiceCommand = args.service_command
    if command.service is Service.ROS2 and args.fleet:
        return _serve_fleet(command, args)
    config = config_from_args(command, args)
    apply_realtime(config.rt, f"invent {command.service}")
    stop = stop_on_signals()
    with open_session(_session_config(args, timestamping=command.timestamped)) as session:
        return run_service(command, session, config, args, stop)


def _serve_fleet(command: ServiceCommand, args: argparse.Namespace) -> int:
    """``invent ros2 --fleet FILE``: a bridge per robot, each in its namespace, in this process."""
    given = {"--robot": args.robot, "--namespace": args.namespace}
    wrong = [flag for flag, value in given.items() if value]
    if wrong:
        raise ConfigError(f"--fleet with {', '.join(wrong)}: each robot's name and namespace are the fleet file's")
    configs = ros2_run.fleet_bridges(load_fleet(args.fleet), args, command)
    stop = stop_on_signals()
    with open_session(_session_config(args, timestamping=command.timestamped)) as session:
        return ros2_run.serve_bridges(command, session, configs, args, stop)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level)
    try:
        return args.handler(args)
    except ConfigError as error:
        print(f"invent {args.command}: invalid configuration: {error}", file=sys.stderr)
        return ExitStatus.CONFIG
    except SessionFailed as error:
        print(f"invent {args.command}: {error}", file=sys.stderr)
        return ExitStatus.FAILURE
