"""Services of one's own (services/extension/, docs/extending.md), fast: the API against real zenoh
(a user service run in this process on a peer session), the loader's refusals, the key space's
user names, and a user service's rights through a real secured router."""

from __future__ import annotations

import json
import queue
import threading
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import msgspec
import pytest
import zenoh

from schemas.keys import Keys, Service, user_service_name
from schemas.messages import Time
from schemas.navigation import GoalReply
from schemas.tokens import parse_alive_key, parse_participant_key, parse_ticks_key
from services.clock.lockstep import OUTPUTS
from services.config import Config
from services.errors import ConfigError
from services.extension.hosting import UserOptions, command
from services.extension.loader import load, load_all
from services.launch.fleet import FleetRobots
from services.launch.plan import UpPlan
from services.security import Role, UserServiceGrant, user_service_grants, write_fleet_profile, write_profile
from services.security.grants import Message
from services.service import ServicePlan, run_service, start_service
from tests.harness import (
    REPO,
    call,
    free_port,
    peer_session,
    refused,
    running_router,
    status_reply,
    wait_alive,
    wait_until,
)

KEYS = Keys()
DATA = Path(__file__).parent / "data" / "extension"
SERVICES = DATA / "services.py"
ODOMETER = REPO / "examples" / "services" / "odometer.py"
PATROL = REPO / "examples" / "services" / "patrol.py"


class Number(msgspec.Struct, frozen=True):
    tm: Time
    value: float


def _spec(name: str, path: Path = SERVICES) -> str:
    return f"{path}:{name}"


# --- the key space ---


def test_a_user_service_name_is_one_lower_case_chunk_never_a_builtins_nor_reserved():
    assert user_service_name("odometer") == "odometer"
    for bad in ("motor", "sim", "up", "view", "operator", "control", "Loud", "a/b", "a*", "", "9lives", "x" * 33):
        with pytest.raises(ValueError):
            user_service_name(bad)


def test_tokens_of_user_services_parse_and_a_user_participant_names_its_output():
    odometer = user_service_name("odometer")
    assert parse_alive_key(KEYS.alive(odometer)) == ("rh0", "odometer")
    assert parse_alive_key("invent/rh0/no*thing/alive") is None
    token = KEYS.ticks_with_output(odometer, 10.0, "distance")
    assert token == "invent/rh0/odometer/ticks/10.0/distance"
    participant = parse_participant_key(token, OUTPUTS)
    assert participant is not None and participant.output == "odometer/distance" and participant.rate_hz == 10.0
    assert parse_participant_key(KEYS.ticks(Service.DRIVE, 50.0), OUTPUTS).output == "drive/target_velocity"
    assert parse_participant_key(KEYS.ticks(odometer, 10.0), OUTPUTS) is None, "a user participant names its output"
    assert parse_participant_key(f"{KEYS.ticks(Service.DRIVE, 50.0)}/x", OUTPUTS) is None
    assert parse_participant_key(f"{KEYS.ticks(odometer, 10.0)}/status", OUTPUTS) is None
    assert parse_ticks_key(token) is None
    with pytest.raises(ValueError):
        KEYS.own(odometer, "a/*")


# --- the loader ---


@pytest.mark.parametrize(
    ("spec", "named"),
    [
        ("nowhere.py:Thing", "no such file"),
        (f"{SERVICES}", "FILE.py:NAME"),
        (f"{SERVICES}:Missing", "defines no Missing"),
        (f"{SERVICES}:NotAService", "not a subclass"),
        (f"{SERVICES}:Named", "built-in"),
        (f"{SERVICES}:Upper", "must match"),
        (f"{SERVICES}:Reserved", "reserved"),
        (f"{SERVICES}:Nameless", "name must be set"),
        (f"{SERVICES}:BadRate", "rate_hz"),
        (f"{SERVICES}:Wildcard", "drive/**"),
        (f"{SERVICES}:ReadsWildcard", "sim/**"),
        (f"{DATA / 'broken.py'}:Thing", "broken on purpose"),
    ],
)
def test_the_loader_refuses_a_bad_file_or_class_naming_it(spec, named):
    with pytest.raises(ConfigError) as refusal:
        load(spec)
    assert spec in str(refusal.value) and named in str(refusal.value)


def test_two_services_of_one_name_clash():
    with pytest.raises(ConfigError, match="taken already"):
        load_all([_spec("Doubler"), _spec("Doubler")])


def test_invent_service_and_up_with_exit_2_naming_a_bad_spec(capsys):
    code, _out, err = refused(capsys, "service", _spec("Named"))
    assert code == 2 and "Named" in err and "built-in" in err
    code, _out, err = refused(capsys, "up", "--with", _spec("Missing"), "--report", "/nonexistent/never")
    assert code == 2 and "defines no Missing" in err
    code, _out, err = refused(
        capsys, "up", "--composed", "--restart", "motor=on-failure", "--with", f"{ODOMETER}:Odometer"
    )
    assert code == 2 and "--restart motor=on-failure: no such service in this run (one of odometer)" in err


# --- the API against real zenoh ---


@contextmanager
def _hosted(endpoint: str, spec: str) -> Iterator[tuple[threading.Thread, list[int]]]:
    """``spec`` run as ``invent service`` runs it, on a peer session of this process, until the end."""
    loaded = load(spec)
    plan = ServicePlan(command(loaded), Config(), UserOptions(loaded))
    stop = threading.Event()
    code: list[int] = []
    with peer_session(endpoint) as session:
        thread = threading.Thread(target=lambda: code.append(run_service(plan, session, stop)), daemon=True)
        thread.start()
        try:
            yield thread, code
        finally:
            stop.set()
            thread.join(10)


def test_the_api_inputs_outputs_queryables_calls_timers_status_and_its_end_over_real_zenoh():
    doubler = user_service_name("doubler")
    with running_router() as endpoint, peer_session(endpoint) as session, _hosted(endpoint, _spec("Doubler")) as run:
        thread, code = run
        wait_alive(session, KEYS.alive(doubler))
        outputs: queue.Queue[bytes] = queue.Queue()
        session.declare_subscriber(KEYS.own(doubler, "output"), lambda s: outputs.put(s.payload.to_bytes()))
        publisher = session.declare_publisher(KEYS.own(doubler, "input"))
        wait_until(lambda: publisher.matching_status.matching, 10, "the doubler to subscribe")
        status_reply(session, KEYS, doubler)  # the runtime's fields decode as a user service's, its own beside them
        wait_until(lambda: call(session, KEYS.status(doubler))[1]["outputs"] == {"output": 0}, 5, "its status")
        publisher.put(msgspec.json.encode(Number(tm=Time(sec=1, nsec=0), value=1.5)))
        assert msgspec.json.decode(outputs.get(timeout=5), type=Number).value == 3.0
        publisher.put(b'{"tm": {"sec": 1, "nsec": 0}, "value": -1.0}')  # the handler's BadInput
        publisher.put(b"not json")  # does not decode
        assert call(session, KEYS.own(doubler, "scale"), b'{"value": 10.0}') == (True, {"factor": 10.0})
        publisher.put(msgspec.json.encode(Number(tm=Time(sec=2, nsec=0), value=1.5)))
        assert msgspec.json.decode(outputs.get(timeout=5), type=Number).value == 15.0
        ok, bad = call(session, KEYS.own(doubler, "scale"), b'{"value": "ten"}')
        assert not ok and "Expected `float`" in bad["error"]
        # a wildcard query reaches what reads, never what acts
        looked = [str(r.ok.key_expr) for r in session.get(f"{KEYS.prefix}/doubler/*", timeout=2.0) if r.ok]
        assert KEYS.own(doubler, "echo") in looked and KEYS.own(doubler, "scale") not in looked
        # a call to a queryable it declares: the stand-in drive answers it, on the service thread
        drive = session.declare_queryable(
            KEYS.drive_goal_send, lambda q: q.reply(q.key_expr, msgspec.json.encode(GoalReply(True, "g7")))
        )
        call(session, KEYS.own(doubler, "ask"), b'{"value": 1.0}')
        status = wait_until(
            lambda: (s := call(session, KEYS.status(doubler))[1])["replies"] and s, 5, "the call's reply"
        )
        drive.undeclare()
        assert status["replies"] == ["g7"] and status["calls"] == {"sent": 1, "replied": 1, "failed": 0}
        by_key = status["bad_input"]["by_key"]  # two samples, one query: counted, never fatal
        assert {key: bad["count"] for key, bad in by_key.items()} == {
            KEYS.own(doubler, "input"): 2,
            KEYS.own(doubler, "scale"): 1,
        }
        assert status["service"] == "doubler" and status["lockstep"] is None
        wait_until(lambda: call(session, KEYS.status(doubler))[1]["timer_ticks"] >= 2, 5, "its timer to run twice")
        assert thread.is_alive(), "bad input never ends the service"
        call(session, KEYS.own(doubler, "stop"))
        thread.join(10)
        assert code == [7], "ctx.finish(7): the service ends by itself with its code"


def test_a_lockstep_output_must_be_declared_and_stamped_and_an_input_read():
    with running_router() as endpoint, peer_session(endpoint) as session:
        for name, why in (
            ("UndeclaredOutput", "was not declared"),
            ("UnstampedOutput", "has no tm stamp"),
            ("ReadsUndeclared", "'invent/rh0/odometry/pose' is not in ReadsUndeclared.reads"),
        ):
            loaded = load(_spec(name))
            with pytest.raises(ConfigError, match=why):
                start_service(ServicePlan(command(loaded), Config(), UserOptions(loaded)), session)


def test_the_odometer_alone_adds_up_the_poses_it_takes():
    odometer = user_service_name("odometer")
    with running_router() as endpoint, peer_session(endpoint) as session, _hosted(endpoint, f"{ODOMETER}:Odometer"):
        wait_alive(session, KEYS.ticks_with_output(odometer, 10.0, "distance"))
        poses = session.declare_publisher(KEYS.odometry_pose)
        wait_until(lambda: poses.matching_status.matching, 10, "the odometer to subscribe")
        for step in range(11):  # 0.1 m every 10 ms of simulation time: 1 m in 0.1 s
            pose = {"tm": {"sec": 0, "nsec": step * 10_000_000}, "id": [], "x": step * 0.1, "y": 0.0, "theta": 0.0}
            poses.put(json.dumps({**pose, "error": []}))
        status = wait_until(lambda: (s := call(session, KEYS.status(odometer))[1])["poses"] == 11 and s, 5, "11 poses")
        assert status["distance_m"] == pytest.approx(1.0)
        assert status["outputs"] == {"distance": 2}, "its ticks at 0 and 0.1 s of simulation time"
        assert status["speed_m_s"] == pytest.approx(10.0)


# --- rights, through a real secured router ---


def test_a_user_service_is_granted_its_own_keys_the_observers_reading_and_its_calls_only():
    patrol = UserServiceGrant(user_service_name("patrol"), ("drive/goal/send",))
    granted = user_service_grants(patrol, KEYS)
    puts = {
        key for grant in granted if Message.PUT in grant.messages and grant.flow == "ingress" for key in grant.key_exprs
    }
    queries = {
        key
        for grant in granted
        if Message.QUERY in grant.messages and grant.flow == "ingress"
        for key in grant.key_exprs
    }
    assert puts == {"invent/rh0/patrol/**"}
    assert KEYS.drive_goal_send in queries and KEYS.drive_goal_cancel not in queries


def test_the_router_lets_a_user_service_put_and_serve_only_under_its_name_and_query_only_its_calls(tmp_path):
    patrol = user_service_name("patrol")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    profile = write_profile(
        tmp_path / "secrets",
        KEYS,
        endpoint=endpoint,
        user_services=[UserServiceGrant(patrol, ("drive/goal/send",))],
    )
    with ExitStack() as stack:
        stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.router_config))))

        def open_file(path: Path) -> zenoh.Session:
            return stack.enter_context(zenoh.open(zenoh.Config.from_file(str(path))))

        # the witness reads every key and answers invent view's status; the drive serves its goals and status
        witness = open_file(profile.client_config(Role.OBSERVER))
        received: queue.Queue[str] = queue.Queue()
        witness.declare_subscriber(KEYS.everything, lambda s: received.put(str(s.key_expr)))
        barrier = KEYS.view_status
        witness.declare_queryable(barrier, lambda q: q.reply(barrier, b"{}"))
        drive = open_file(profile.client_config(Role.DRIVE))
        for key in (KEYS.drive_goal_send, KEYS.drive_goal_cancel):
            drive.declare_queryable(key, lambda q: q.reply(q.key_expr, b'{"accepted": true, "id": "g1"}'))
        drive_status = KEYS.status(Service.DRIVE)
        drive.declare_queryable(drive_status, lambda q: q.reply(drive_status, b"{}"))
        user = open_file(profile.user_service_config(patrol))
        own, foreign = KEYS.own(patrol, "progress"), (KEYS.motor_torque, KEYS.drive_target_velocity)
        publishers = [user.declare_publisher(key) for key in (own, *foreign)]
        wait_until(lambda: all(p.matching_status.matching for p in publishers), 10, "the witness to match")
        for publisher in publishers:
            publisher.put(b"{}")
        # after its puts, in order: the witness asks the user service's own status, which it serves
        own_status = KEYS.status(patrol)
        user.declare_queryable(own_status, lambda q: q.reply(own_status, b"{}"))
        wait_until(lambda: [r for r in witness.get(own_status, timeout=1.0) if r.ok], 10, "its status")
        wait_until(lambda: [r for r in witness.get(drive_status, timeout=1.0) if r.ok], 10, "the drive's queryables")
        delivered = set()
        while not received.empty():
            delivered.add(received.get())
        assert delivered == {own}, "only its own key's put gets through"
        assert [r.ok is not None for r in user.get(KEYS.drive_goal_send, timeout=2.0)] == [True]
        assert not [r for r in user.get(KEYS.drive_goal_cancel, timeout=2.0) if r.ok], "not in its calls"
        answered = [str(r.ok.key_expr) for r in user.get(KEYS.every_status, timeout=2.0) if r.ok]
        assert answered == [own_status], "no other service's status (not in its calls): only its own, in its session"
        tokens: set[str] = set()
        witness.liveliness().declare_subscriber(KEYS.every_alive, lambda s: tokens.add(str(s.key_expr)), history=True)
        witness.liveliness().declare_subscriber(KEYS.every_ticks, lambda s: tokens.add(str(s.key_expr)), history=True)
        wait_until(lambda: witness.get(own_status, timeout=5.0), 5, "the witness's subscribers")  # declared before
        held = [user.liveliness().declare_token(KEYS.alive(patrol))]
        held.append(user.liveliness().declare_token(KEYS.alive(Service.DRIVE)))
        held.append(user.liveliness().declare_token(KEYS.ticks_with_output(patrol, 10.0, "progress")))
        # in order through one transport: once its ticks token is there, the drive's would have been
        wait_until(lambda: KEYS.ticks_with_output(patrol, 10.0, "progress") in tokens, 5, "its ticks token")
        assert tokens == {KEYS.alive(patrol), KEYS.ticks_with_output(patrol, 10.0, "progress")}


# --- a fleet's services of one's own ---


def test_a_fleet_file_runs_services_of_ones_own_beside_every_robot_or_one(tmp_path):
    fleet_file = tmp_path / "fleet.toml"
    fleet_file.write_text(
        f'with = ["{ODOMETER}:Odometer"]\n'
        '[[robots]]\nname = "rh0"\n'
        f'[[robots]]\nname = "rh1"\nstart = {{ x = 0.0, y = 3.0, theta = 0.0 }}\nwith = ["{_spec("Doubler")}"]\n'
    )
    robots = FleetRobots(UpPlan(fleet=str(fleet_file)), str(fleet_file))
    assert {robot.name: [user.name for user in robot.extensions] for robot in robots.each} == {
        "rh0": ["odometer"],
        "rh1": ["odometer", "doubler"],
    }
    assert [robot.participants for robot in robots.each] == [("odometer",), ("odometer",)]
    access = robots.access(tmp_path / "run")
    assert access.user_service_file("odometer", "rh1") is None  # not secure: zenoh's defaults
    fleet_file.write_text(f'[[robots]]\nname = "rh0"\nwith = ["{_spec("Named")}"]\n')
    with pytest.raises(ConfigError, match="fleet robot 'rh0': .*built-in"):
        FleetRobots(UpPlan(fleet=str(fleet_file)), str(fleet_file))


def test_a_secure_fleets_user_service_is_granted_its_own_robots_keys_only(tmp_path):
    doubler = user_service_name("doubler")
    profile = write_fleet_profile(
        tmp_path / "secrets",
        ["rh0", "rh1"],
        endpoint="tcp/127.0.0.1:7447",
        user_services={"rh1": [UserServiceGrant(doubler)]},
    )
    assert profile.user_service_config("doubler", "rh1").name == "rh1-doubler.json5"
    with pytest.raises(ValueError):
        profile.user_service_config("doubler", "rh0")
    router = json.loads(str(zenoh.Config.from_file(str(profile.router_config))))
    rules = {rule["id"]: rule for rule in router["access_control"]["rules"]}
    puts = [
        key
        for rule in rules.values()
        if rule["id"].startswith("rh1-doubler-") and "put" in rule["messages"] and rule["flows"] == ["ingress"]
        for key in rule["key_exprs"]
    ]
    assert puts == ["invent/rh1/doubler/**"]
