"""Several machines, for real: a router per host, the hosts' routers linked to a hub's, in Linux
network namespaces (tests/netns.py; root only, skipped with the reason elsewhere).

The hub is the sim server, host1 and host2 are two robots' computers. Each runs ``invent router``
listening on its loopback and its own address; the robots' routers ``--connect`` to the hub's.
The zenoh sessions are opened as the services open theirs (``session_config``, peer mode,
multicast scouting off), each connected to its own host's router. What docs/deploy.md says about
links that drop is what the last two tests measure.
"""

from __future__ import annotations

import itertools
import json
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from services.runtime.session import DEFAULT_ENDPOINT
from tests.harness import wait_until
from tests.netns import REPO, HostProcess, Network, netns_unavailable, network
from tests.remote_session import Event, RemoteSession, Stream

PREFIX = "fleet-test"
PERIOD_S = 0.02
"""Each robot host publishes a counter at 50 Hz."""
LEASE_S = json.loads(zenoh.Config().get_json("transport/link/tx/lease")) / 1000
"""zenoh's default lease (10 s): a link silent that long is closed, its tokens undeclared."""
RETRY_MAX_S = 4.0
"""zenoh's default ``connect/retry/period_max_ms``: a router retries its ``--connect`` endpoint at
1, 2, 4, 4, ... s after losing it, for ever (a router's ``connect/timeout_ms`` is -1)."""
RECONNECT_BOUND_S = RETRY_MAX_S + 8.0
"""From a link's return to the token seen again: the wait before the next retry, plus an attempt
begun while the link was down failing first (ARP gives up after about 3 s), plus slack."""
MAX_GAP_S = 1.0
"""Host1's counter, at 50 Hz, never pauses that long (a loaded machine's scheduling included)."""
DOC_SIM_SERVER = "192.168.10.1"
"""The sim server's address in docs/deploy.md's examples."""
ORCHESTRATOR_LOG = {"RUST_LOG": "zenoh::net::runtime::orchestrator=debug"}
"""zenoh's connection attempts, in a session's stderr."""


def counter_key(host: str) -> str:
    return f"{PREFIX}/{host}/counter"


@dataclass
class Fleet:
    net: Network
    routers: dict[str, HostProcess]
    router_zids: dict[str, str]
    sessions: dict[str, RemoteSession]
    counters: Stream
    """The hub's subscription to every host's counter."""
    alive: Stream
    """The hub's liveliness subscription."""

    def samples(self, host: str, after: float = -1.0, before: float = float("inf")) -> list[Event]:
        return [e for e in self.counters.snapshot() if e["key"] == counter_key(host) and after < e["t"] < before]

    def wait_sample(self, host: str, after: float, timeout: float, what: str) -> Event:
        return self.counters.wait_for(lambda e: e["key"] == counter_key(host), timeout, what, since=after)


def _router(net: Network, host: str, *args: str) -> tuple[HostProcess, str]:
    process = net.invent(host, "router", "--listen", DEFAULT_ENDPOINT, "--listen", net[host].endpoint(), *args)
    line = process.wait_for_line(r"^invent router \S+ listening on")
    return process, line.split()[2]


@pytest.fixture
def fleet() -> Iterator[Fleet]:
    reason = netns_unavailable()
    if reason:
        pytest.skip(f"network namespaces cannot be made here: {reason}")
    with network("hub", "host1", "host2") as net:
        hub_router, hub_zid = _router(net, "hub")
        routers, zids = {"hub": hub_router}, {"hub": hub_zid}
        for host in ("host1", "host2"):
            routers[host], zids[host] = _router(net, host, "--connect", net["hub"].endpoint())
        sessions = {
            # no --connect: the default endpoint, the host's own router on its loopback
            "hub": net.session("hub", env=ORCHESTRATOR_LOG),
            "host1": net.session("host1", env=ORCHESTRATOR_LOG),
            "host1b": net.session("host1", env=ORCHESTRATOR_LOG),
            # or the router's address on the host's network
            "host2": net.session("host2", connect=[net["host2"].endpoint()], env=ORCHESTRATOR_LOG),
        }
        hub = sessions["hub"]
        counters = hub.subscribe(f"{PREFIX}/*/counter")
        alive = hub.liveliness(f"{PREFIX}/*/alive")
        sessions["host1"].publish_every(counter_key("host1"), PERIOD_S)
        sessions["host2"].publish_every(counter_key("host2"), PERIOD_S)
        sessions["host2"].queryable(f"{PREFIX}/host2/echo", {"from": "host2"})
        sessions["host2"].token(f"{PREFIX}/host2/alive")
        yield Fleet(net, routers, zids, sessions, counters, alive)
        codes = {name: session.close() for name, session in sessions.items()}
        codes |= {f"{host} router": router.stop() for host, router in routers.items()}
        assert codes == dict.fromkeys(codes, 0), {name: router.stderr for name, router in routers.items()}
        assert net.close() == []


def test_linked_routers_carry_samples_queries_and_tokens_between_hosts(fleet: Fleet) -> None:
    fleet.wait_sample("host1", -1, 20, "host1's counter at the hub")
    fleet.wait_sample("host2", -1, 20, "host2's counter at the hub")
    fleet.alive.wait_for(lambda e: e["key"] == f"{PREFIX}/host2/alive" and e["kind"] == "put", 20, "host2's token")
    assert fleet.sessions["hub"].get(f"{PREFIX}/host2/echo") == [{"from": "host2"}]
    # robot to robot: host1's router, the hub's, host2's
    assert fleet.sessions["host1"].get(f"{PREFIX}/host2/echo") == [{"from": "host2"}]

    # Each session is linked to its own host's router only; the two peers of host1 to each other
    # (gossip, over their loopback listeners); nothing across hosts but the routers' links.
    zids = {name: session.zid for name, session in fleet.sessions.items()}
    expected = {
        "hub": {"routers": [fleet.router_zids["hub"]], "peers": []},
        "host1": {"routers": [fleet.router_zids["host1"]], "peers": [zids["host1b"]]},
        "host1b": {"routers": [fleet.router_zids["host1"]], "peers": [zids["host1"]]},
        "host2": {"routers": [fleet.router_zids["host2"]], "peers": []},
    }

    def links() -> dict[str, dict[str, list[str]]]:
        infos = {name: session.info() for name, session in fleet.sessions.items()}
        return {name: {"routers": info["routers"], "peers": info["peers"]} for name, info in infos.items()}

    try:
        wait_until(lambda: links() == expected, 10, "each session's links")
    except AssertionError:
        assert links() == expected
    # ... and gossip never had a session try anything off its own host (zenoh's log says each
    # attempt: the configured router, then each gossiped peer "via any of [locators]").
    for name, session in fleet.sessions.items():
        log = re.sub(r"\x1b\[[0-9;]*m", "", session.process.stderr)
        assert "Try to connect" in log, f"zenoh's orchestrator log changed wording; {name}'s log:\n{log}"
        assert "Unable to connect" not in log, f"{name} failed to connect somewhere:\n{log}"
        tried = re.findall(r"Try to connect to peer \S+ via any of \[([^\]]*)\]", log)
        assert all(locator.startswith("tcp/127.0.0.1:") for attempt in tried for locator in attempt.split(", ")), (
            f"{name} tried a peer off its host: {tried}"
        )


def _max_gap(events: list[Event], start: float, end: float) -> float:
    times = [start, *(e["t"] for e in events if start < e["t"] < end), end]
    return max(later - earlier for earlier, later in itertools.pairwise(times))


@pytest.mark.slow
def test_a_link_cut_shorter_than_the_lease_delays_that_host_and_loses_nothing(fleet: Fleet) -> None:
    """A 2 s cut: TCP holds the link (zenoh's lease is 10 s), the token stays, host2's samples
    stop and then arrive late, every one of them; host1 never notices."""
    cut_s = 2.0
    before = fleet.wait_sample("host2", -1, 20, "host2's counter at the hub")
    fleet.wait_sample("host1", -1, 20, "host1's counter at the hub")
    with fleet.net.link_cut("host2"):
        cut = time.monotonic()
        # the cut lasts while host1's samples go on arriving: they time it
        fleet.wait_sample("host1", cut + cut_s, cut_s + 5, "host1's counter during the cut")
    restored = time.monotonic()
    first = fleet.wait_sample("host2", restored, 10, "host2's counter after the cut")
    # a further second of samples, to see the backlog drained
    fleet.wait_sample("host2", first["t"] + 1.0, 10, "host2's counter a second after the cut")

    gap = _max_gap(fleet.samples("host1"), cut, restored)
    assert gap < MAX_GAP_S, f"host1's samples paused {gap:.3f} s during host2's cut"
    assert fleet.samples("host2", after=cut + 0.25, before=restored) == [], "host2's samples crossed a cut link"
    seqs = [e["value"]["seq"] for e in fleet.samples("host2")]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a short cut lost or reordered samples"
    assert seqs[-1] - before["value"]["seq"] > cut_s / PERIOD_S, "host2 published less than the cut lasted"
    assert [e["kind"] for e in fleet.alive.snapshot()] == ["put"], "host2's token went during a short cut"
    print(
        f"short cut: host2's samples back {first['t'] - restored:.3f} s after the link; host1's longest gap {gap:.3f} s"
    )


@pytest.mark.slow
def test_a_link_cut_longer_than_the_lease_drops_that_host_until_its_router_reconnects(fleet: Fleet) -> None:
    """The hub drops host2 after the lease (its token goes, its queryable is gone); host1 never
    notices; once the cable is back, host2's router reconnects by itself, within its retry period:
    the token, the samples and the answers come back. On host2 itself, nothing stops."""
    token = f"{PREFIX}/host2/alive"
    local = fleet.net.session("host2").subscribe(counter_key("host2"))  # another service of host2
    fleet.alive.wait_for(lambda e: e["key"] == token and e["kind"] == "put", 20, "host2's token")
    fleet.wait_sample("host2", -1, 20, "host2's counter at the hub")
    local.wait_for(lambda e: True, 20, "host2's counter on host2")
    fleet.wait_sample("host1", -1, 20, "host1's counter at the hub")
    fleet.net.cut("host2")
    try:
        cut = time.monotonic()
        gone = fleet.alive.wait_for(
            lambda e: e["key"] == token and e["kind"] == "delete", LEASE_S + 5, "host2's token to go", since=cut
        )
        assert fleet.sessions["hub"].get(f"{PREFIX}/host2/echo", timeout=1.0) == []
        # down for 2 s more, the router's retries failing meanwhile (timed by host1's samples)
        fleet.wait_sample("host1", gone["t"] + 2.0, 10, "host1's counter while host2 is gone")
    finally:
        fleet.net.restore("host2")
    restored = time.monotonic()
    back = fleet.alive.wait_for(
        lambda e: e["key"] == token and e["kind"] == "put", RECONNECT_BOUND_S, "host2's token back", since=restored
    )
    flowing = fleet.wait_sample("host2", restored, RECONNECT_BOUND_S, "host2's counter back")
    assert fleet.sessions["hub"].get(f"{PREFIX}/host2/echo") == [{"from": "host2"}]

    assert LEASE_S - 1.0 < gone["t"] - cut < LEASE_S + 5, f"the token went {gone['t'] - cut:.3f} s after the cut"
    gap = _max_gap(fleet.samples("host1"), cut, flowing["t"])
    assert gap < MAX_GAP_S, f"host1's samples paused {gap:.3f} s during host2's cut"
    local_gap = _max_gap(local.snapshot(), cut, flowing["t"])
    assert local_gap < MAX_GAP_S, f"host2's own samples paused {local_gap:.3f} s on host2 during its cut"
    assert fleet.samples("host2", after=cut + 0.25, before=restored) == [], "host2's samples crossed a cut link"
    print(
        f"long cut: token gone {gone['t'] - cut:.3f} s after the cut; back {back['t'] - restored:.3f} s and "
        f"samples {flowing['t'] - restored:.3f} s after the link; host1's longest gap {gap:.3f} s, "
        f"host2's on host2 {local_gap:.3f} s"
    )


def _json5_block(text: str, first_line: str) -> str:
    """The ```json5 block of docs/deploy.md whose first line is ``first_line``."""
    blocks = re.findall(r"```json5\n(.*?)```", text, re.DOTALL)
    found = [block for block in blocks if block.startswith(first_line)]
    assert len(found) == 1, f"docs/deploy.md has {len(found)} json5 blocks starting {first_line!r}"
    return found[0]


def test_the_router_files_of_deploy_md_link_a_robot_to_the_sim_server(tmp_path: Path) -> None:
    reason = netns_unavailable()
    if reason:
        pytest.skip(f"network namespaces cannot be made here: {reason}")
    doc = (REPO / "docs" / "deploy.md").read_text()
    with network("hub", "host1") as net:
        files = {}
        for host, name in (("hub", "sim-server.json5"), ("host1", "robot.json5")):
            files[host] = tmp_path / name
            files[host].write_text(_json5_block(doc, f"// {name}").replace(DOC_SIM_SERVER, net["hub"].address))
        hub_router = net.invent("hub", "router", "--config", str(files["hub"]))
        hub_router.wait_for_line(r"^invent router \S+ listening on tcp/0\.0\.0\.0:7447")
        robot_router = net.invent("host1", "router", "--config", str(files["host1"]))
        robot_router.wait_for_line(r"^invent router \S+ listening on tcp/127\.0\.0\.1:7447")
        hub, robot = net.session("hub"), net.session("host1")  # both on the default endpoint
        alive = hub.liveliness(f"{PREFIX}/*/alive")
        counters = hub.subscribe(f"{PREFIX}/*/counter")
        robot.token(f"{PREFIX}/host1/alive")
        robot.queryable(f"{PREFIX}/host1/echo", {"from": "host1"})
        robot.publish_every(counter_key("host1"), PERIOD_S)
        alive.wait_for(lambda e: e["kind"] == "put", 20, "the robot's token at the sim server")
        counters.wait_for(lambda e: e["key"] == counter_key("host1"), 20, "the robot's counter at the sim server")
        assert hub.get(f"{PREFIX}/host1/echo") == [{"from": "host1"}]
        assert robot.info()["routers"] == [robot_router.wait_for_line("listening").split()[2]]
        assert [hub.close(), robot.close(), robot_router.stop(), hub_router.stop()] == [0, 0, 0, 0]
        assert net.close() == []
