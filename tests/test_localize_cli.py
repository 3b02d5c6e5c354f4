"""``invent localize`` as a process against a stand-in localization on a real router: a peer
session serving ``localization/initial_pose`` and ``localization/global_localization`` notes what it
is sent and replies; the tool's exit for each path (accepted 0, refused 1 with the reason, nothing
answering 1 naming the key and why, bad arguments 2 before any session)."""

from __future__ import annotations

import queue
from collections.abc import Callable, Iterator

import pytest
import zenoh

from schemas.codec import decode, encode
from schemas.keys import Keys, Service
from schemas.messages import NoArguments
from schemas.navigation import InitialPose, LocalizationReply
from services.cli.localize import covariance
from services.exits import ExitStatus
from tests.harness import peer_session, refused, run_invent, running_router, wait_until

KEYS = Keys("rh3")


@pytest.fixture
def endpoint() -> Iterator[str]:
    with running_router() as endpoint:
        yield endpoint


class StandInLocalization:
    """The two queryables of an amcl localization on ``session``: each query's key and payload
    queued, each answered ``reply``."""

    def __init__(self, session: zenoh.Session, reply: LocalizationReply) -> None:
        self.asked: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self._reply = encode(reply)
        self._queryables = [
            session.declare_queryable(key, self._answer)
            for key in (KEYS.localization_initial_pose, KEYS.localization_global_localization)
        ]

    def _answer(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self.asked.put((str(query.key_expr), payload))
        query.reply(query.key_expr, self._reply)

    def close(self) -> None:
        for queryable in self._queryables:
            queryable.undeclare()


def _localize(endpoint: str, *args: str, wait: str = "5") -> tuple[int, str, str]:
    result = run_invent("localize", *args, "--robot", KEYS.robot, "--wait", wait, "--connect", endpoint)
    return result.returncode, result.stdout, result.stderr


def _served(endpoint: str, reply: LocalizationReply, ask: Callable[[], tuple[int, str, str]]):
    with peer_session(endpoint) as session:
        stand_in = StandInLocalization(session, reply)
        try:
            code, out, err = ask()
            asked = []
            while not stand_in.asked.empty():
                asked.append(stand_in.asked.get_nowait())
        finally:
            stand_in.close()
    return code, out, err, asked


def test_the_covariance_is_the_upper_triangle_of_the_sigmas_diagonal_or_none():
    assert covariance(0.5, 0.25) == [0.25, 0.0, 0.0, 0.25, 0.0, 0.0625]
    assert covariance(None, None) == []
    with pytest.raises(ValueError, match="both"):
        covariance(0.5, None)


def test_an_initial_pose_with_sigmas_is_sent_and_accepted_exit_0(endpoint):
    code, out, err, asked = _served(
        endpoint,
        LocalizationReply(True),
        lambda: _localize(endpoint, "-1.5", "2", "0.75", "--sigma-xy", "0.5", "--sigma-theta", "0.25"),
    )
    assert code == ExitStatus.OK, err
    [(key, payload)] = asked
    assert key == KEYS.localization_initial_pose
    assert decode(InitialPose, payload) == InitialPose(
        x=-1.5, y=2.0, theta=0.75, covariance=[0.25, 0.0, 0.0, 0.25, 0.0, 0.0625]
    )
    assert out.strip() == (
        "initial pose x -1.500 y +2.000 theta +0.750 (sigma xy 0.500 m, sigma theta 0.250 rad) "
        "accepted by rh3's localization"
    )


def test_without_sigmas_the_covariance_is_empty_and_a_refusal_exits_1_with_the_reason(endpoint):
    code, out, err, asked = _served(
        endpoint, LocalizationReply(False, "(9.0, 9.0) is off the map"), lambda: _localize(endpoint, "9", "9", "0")
    )
    assert code == ExitStatus.FAILURE
    [(key, payload)] = asked
    assert key == KEYS.localization_initial_pose
    assert decode(InitialPose, payload) == InitialPose(x=9.0, y=9.0, theta=0.0)
    assert decode(InitialPose, payload).covariance == []
    assert out == ""
    assert "rh3's localization refused the initial pose" in err
    assert "(9.0, 9.0) is off the map" in err


def test_global_sends_no_arguments_on_its_own_key(endpoint):
    code, out, err, asked = _served(endpoint, LocalizationReply(True), lambda: _localize(endpoint, "--global"))
    assert code == ExitStatus.OK, err
    [(key, payload)] = asked
    assert key == KEYS.localization_global_localization
    assert decode(NoArguments, payload) == NoArguments()
    assert out.strip() == "global localization accepted by rh3's localization"


def test_no_localization_running_exits_1_naming_the_key(endpoint):
    code, out, err = _localize(endpoint, "1", "2", "0", wait="0.5")
    assert code == ExitStatus.FAILURE
    assert out == ""
    assert KEYS.localization_initial_pose in err
    assert "no localization of rh3 is running" in err


def test_a_localization_alive_not_serving_it_is_said_not_in_amcl_mode(endpoint):
    """The stub (and none) hold the localization's token but serve no initial_pose."""
    with peer_session(endpoint) as session:
        token = session.liveliness().declare_token(KEYS.alive(Service.LOCALIZATION))
        with peer_session(endpoint) as observer:
            wait_until(
                lambda: any(
                    reply.ok is not None
                    for reply in observer.liveliness().get(KEYS.alive(Service.LOCALIZATION), timeout=1.0)
                ),
                what="the localization's token at the router",
            )
        try:
            code, _out, err = _localize(endpoint, "--global", wait="0.5")
        finally:
            token.undeclare()
    assert code == ExitStatus.FAILURE
    assert KEYS.localization_global_localization in err
    assert 'only localization.mode = "amcl"' in err


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("1", "nan", "0"), "not finite"),
        (("1", "2", "inf"), "not finite"),
        (("1", "2", "0", "--sigma-xy", "-0.1", "--sigma-theta", "0.1"), "--sigma-xy"),
        (("1", "2", "0", "--sigma-xy", "0.1"), "both --sigma-xy and --sigma-theta"),
        (("1", "2"), "give X Y THETA"),
        (("1", "2", "0", "--global"), "--global takes no X Y THETA"),
        (("--global", "--sigma-xy", "0.1", "--sigma-theta", "0.1"), "--global takes no"),
    ],
    ids=["nan", "inf", "negative-sigma", "sigma-alone", "no-theta", "global-with-pose", "global-with-sigmas"],
)
def test_bad_arguments_exit_2_before_any_session(capsys, args, says):
    code, out, err = refused(capsys, "localize", *args, "--connect", "tcp/127.0.0.1:9")
    assert code == ExitStatus.CONFIG
    assert out == ""
    assert says in err
