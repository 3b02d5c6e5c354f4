"""Test harness: real Linux network namespaces, so that a test can run "several machines".

:func:`network` makes one namespace per host name, each with loopback up and one veth link
(``eth0`` inside) to a bridge on a private subnet (:data:`SUBNET`, hosts at ``.1``, ``.2``, ... in
the order named); the bridge sits in a namespace of its own (the "switch"), so nothing of the
test touches the machine's own network namespace (its addresses, routes and firewall). Every name
carries the test process's pid and a random token, so parallel runs and leftovers never clash,
and a leftover whose creator died is swept by the next run. Everything is removed when the
context ends, even on failure: the processes started in it first, then the namespaces (which
take their links with them).

In a namespace the test runs processes (:meth:`Network.popen`, :meth:`Network.invent`) and zenoh
sessions (:meth:`Network.session`, a :class:`RemoteSession`: a zenoh session opened the way the
services open theirs, in a small process of its own driven by JSON lines; one process cannot
hold sessions in two namespaces, for zenoh's runtime threads are shared). :meth:`Network.cut`
and :meth:`Network.restore` pull and put back a host's cable (its switch-side veth down/up: the
host sees its link lose carrier, as when a cable or Wi-Fi drops).

Namespaces need root (CAP_SYS_ADMIN, CAP_NET_ADMIN) and iproute2: :func:`netns_unavailable`
says why they cannot be made here, for a test to skip with that reason.

The session processes are tests/remote_session.py's.
"""

from __future__ import annotations

import functools
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

from tests.remote_session import STOP_TIMEOUT_S, RemoteSession

REPO = Path(__file__).resolve().parent.parent
SUBNET = "10.231.0.0/24"
"""The hosts' private subnet (a /24 from RFC 1918 space that nothing here otherwise uses)."""
NAME_PREFIX = "invent-"
"""Every namespace this harness makes is ``invent-<pid>-<token>-<host>``; nothing else is touched."""
IP_TIMEOUT_S = 10.0

_NAME = re.compile(rf"^{re.escape(NAME_PREFIX)}(\d+)-[0-9a-f]+-")


class NetnsError(RuntimeError):
    """An ``ip`` command failed (its command line and stderr are in the message)."""


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    """``ip ARGS``; a failure raises :class:`NetnsError` naming the command and its stderr."""
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=IP_TIMEOUT_S, check=False)
    if check and done.returncode != 0:
        raise NetnsError(f"`ip {' '.join(args)}` failed ({done.returncode}): {done.stderr.strip()}")
    return done


@functools.cache
def netns_unavailable() -> str | None:
    """None when this machine lets the harness make namespaces, else why not (for ``pytest.skip``):
    not root, no ``ip``, or the kernel refused a namespace, a veth pair or a bridge (a container
    without CAP_SYS_ADMIN, a kernel without veth or bridge support). It tries once, for real: a
    namespace with a bridge and a veth pair, removed at once."""
    if sys.platform != "linux":
        return f"network namespaces are Linux only (this is {sys.platform})"
    if os.geteuid() != 0:
        return f"network namespaces need root (CAP_SYS_ADMIN and CAP_NET_ADMIN); running as uid {os.geteuid()}"
    if shutil.which("ip") is None:
        return "`ip` (iproute2) is not on PATH"
    sweep_stale()
    probe = f"{NAME_PREFIX}{os.getpid()}-{secrets.token_hex(3)}-probe"
    try:
        ip("netns", "add", probe)
    except (NetnsError, OSError, subprocess.SubprocessError) as error:
        return f"cannot create a network namespace: {error}"
    try:
        ip("-n", probe, "link", "add", "br0", "type", "bridge")
        ip("-n", probe, "link", "add", "v0", "type", "veth", "peer", "name", "v1")
        ip("-n", probe, "link", "set", "v0", "master", "br0")
    except (NetnsError, OSError, subprocess.SubprocessError) as error:
        return f"cannot make a bridge and a veth pair in a namespace: {error}"
    finally:
        ip("netns", "delete", probe, check=False)
    return None


def _namespaces() -> list[str]:
    return [line.split()[0] for line in ip("netns", "list").stdout.splitlines() if line.strip()]


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, killed and not yet reaped, does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[0] not in ("Z", "X")


def _remove_namespace(name: str) -> list[str]:
    """Kill what still runs in namespace ``name`` (only processes this harness started there) and
    delete it; return the problems met."""
    problems = []
    pids = ip("netns", "pids", name, check=False).stdout.split()
    for pid in pids:
        try:
            os.kill(int(pid), signal.SIGKILL)
            problems.append(f"killed pid {pid} still running in {name}")
        except ProcessLookupError:
            pass
    done = ip("netns", "delete", name, check=False)
    if done.returncode != 0:
        problems.append(f"`ip netns delete {name}`: {done.stderr.strip()}")
    return problems


def sweep_stale() -> list[str]:
    """Remove the namespaces of this harness whose creating process is gone (a run killed before
    its cleanup); return their names."""
    stale = []
    for name in _namespaces():
        match = _NAME.match(name)
        if match and not _pid_alive(int(match.group(1))):
            _remove_namespace(name)
            stale.append(name)
    return stale


@dataclass(frozen=True)
class Host:
    """One namespace: a "machine" with one address on :data:`SUBNET`."""

    name: str
    """The test's name for it (``hub``, ``host1``)."""
    netns: str
    """The namespace's real name (``invent-<pid>-<token>-<name>``)."""
    address: str
    """Its address on the subnet, e.g. ``10.231.0.2``; its interface is ``eth0``."""
    switch_veth: str
    """The switch-side end of its link (in the switch namespace): what :meth:`Network.cut` downs."""

    def endpoint(self, port: int = 7447, protocol: str = "tcp") -> str:
        """A zenoh endpoint on this host's address, e.g. ``tcp/10.231.0.2:7447``."""
        return f"{protocol}/{self.address}:{port}"


class Network:
    """Namespaces on one switch; use :func:`network` (or ``with Network(...)``): it removes
    everything at the end."""

    def __init__(self, names: Sequence[str]) -> None:
        if not names or len(set(names)) != len(names) or not all(re.fullmatch(r"[a-z0-9][a-z0-9-]*", n) for n in names):
            raise ValueError(f"host names must be distinct, at least one, lowercase letters, digits and '-': {names!r}")
        if len(names) > 250:
            raise ValueError("at most 250 hosts on the /24")
        reason = netns_unavailable()
        if reason:
            raise NetnsError(reason)
        token = secrets.token_hex(3)
        base = f"{NAME_PREFIX}{os.getpid()}-{token}-"
        self.switch = base + "switch"
        self.hosts: dict[str, Host] = {}
        self._processes: list[HostProcess] = []
        self._created: list[str] = []
        network_prefix = SUBNET.split("/")[0].rsplit(".", 1)[0]
        try:
            self._add_namespace(self.switch)
            ip("-n", self.switch, "link", "add", "br0", "type", "bridge", "forward_delay", "0")
            ip("-n", self.switch, "link", "set", "br0", "up")
            for index, name in enumerate(names):
                host = Host(
                    name=name,
                    netns=base + name,
                    address=f"{network_prefix}.{index + 1}",
                    # interface names have at most 15 characters: v + token + index
                    switch_veth=f"v{token}{index}",
                )
                self._add_namespace(host.netns)
                veth = ("type", "veth", "peer", "eth0", "netns", host.netns)  # eth0 made in the host's namespace
                ip("-n", self.switch, "link", "add", host.switch_veth, *veth)
                ip("-n", self.switch, "link", "set", host.switch_veth, "master", "br0", "up")
                ip("-n", host.netns, "addr", "add", f"{host.address}/{SUBNET.split('/')[1]}", "dev", "eth0")
                ip("-n", host.netns, "link", "set", "eth0", "up")
                self.hosts[name] = host
        except BaseException:
            self.close()
            raise

    def _add_namespace(self, name: str) -> None:
        ip("netns", "add", name)
        self._created.append(name)
        ip("-n", name, "link", "set", "lo", "up")

    def __getitem__(self, name: str) -> Host:
        return self.hosts[name]

    def _host(self, host: Host | str) -> Host:
        return self.hosts[host] if isinstance(host, str) else host

    def command(self, host: Host | str, *argv: str) -> list[str]:
        """``argv`` run inside ``host``'s namespace: ``ip netns exec NETNS ARGV...`` (which execs
        ARGV in place: the pid is ARGV's own, signals reach it)."""
        return ["ip", "netns", "exec", self._host(host).netns, *argv]

    def run(self, host: Host | str, *argv: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` in ``host`` to its end, output captured."""
        return subprocess.run(
            self.command(host, *argv), cwd=REPO, capture_output=True, text=True, timeout=timeout, check=False
        )

    def popen(
        self,
        host: Host | str,
        *argv: str,
        env: dict[str, str] | None = None,
        on_stdout: Callable[[str], None] | None = None,
    ) -> HostProcess:
        """Start ``argv`` in ``host``; it is stopped (SIGINT, then SIGKILL) when the network closes."""
        process = HostProcess(self.command(host, *argv), env=env, on_stdout=on_stdout)
        self._processes.append(process)
        return process

    def invent(self, host: Host | str, *args: str, env: dict[str, str] | None = None) -> HostProcess:
        """``invent ARGS`` (this checkout's, this Python) in ``host``."""
        return self.popen(host, sys.executable, "-m", "services.cli", *args, env=env)

    def session(
        self,
        host: Host | str,
        *,
        connect: Sequence[str] = (),
        listen: Sequence[str] = (),
        mode: str = "peer",
        env: dict[str, str] | None = None,
    ) -> RemoteSession:
        """A zenoh session in ``host``, configured as a service's (``session_config``: no
        ``connect`` means the default endpoint, the host's own loopback router), closed with the
        network; it is open when this returns. ``env={"RUST_LOG": ...}`` puts zenoh's own log on
        the process's stderr (``session.process.stderr``)."""
        args = ["--mode", mode]
        for endpoint in connect:
            args += ["--connect", endpoint]
        for endpoint in listen:
            args += ["--listen", endpoint]
        return RemoteSession(
            lambda on_line: self.popen(
                host, sys.executable, "-m", "tests.remote_session", *args, env=env, on_stdout=on_line
            )
        )

    def cut(self, host: Host | str) -> None:
        """Pull ``host``'s cable: its switch-side veth down (the host keeps its address; its
        ``eth0`` loses carrier, and nothing it sends reaches anyone)."""
        ip("-n", self.switch, "link", "set", self._host(host).switch_veth, "down")

    def restore(self, host: Host | str) -> None:
        """Plug ``host``'s cable back in."""
        ip("-n", self.switch, "link", "set", self._host(host).switch_veth, "up")

    @contextmanager
    def link_cut(self, host: Host | str) -> Iterator[None]:
        """``host``'s cable pulled for the ``with`` block, put back at its end whatever happens."""
        self.cut(host)
        try:
            yield
        finally:
            self.restore(host)

    def close(self) -> list[str]:
        """Stop every process started here, then delete every namespace; return the problems met
        (processes that had to be killed or were still running). Idempotent."""
        problems = []
        for process in reversed(self._processes):
            problems += process.stop_quietly()
        self._processes.clear()
        for name in reversed(self._created):
            problems += _remove_namespace(name)
        self._created.clear()
        return problems

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


@contextmanager
def network(*names: str) -> Iterator[Network]:
    """Namespaces named ``names`` on one switch, removed at the end of the ``with``."""
    net = Network(names)
    try:
        yield net
    finally:
        net.close()


class HostProcess:
    """A process in a namespace. Threads read its stdout and stderr as the lines come (a full
    pipe would block it); :meth:`wait_for_line` waits for one, :meth:`stop` ends it (SIGINT)."""

    def __init__(
        self,
        argv: Sequence[str],
        env: dict[str, str] | None = None,
        on_stdout: Callable[[str], None] | None = None,
    ) -> None:
        self.argv = list(argv)
        self.process = subprocess.Popen(
            self.argv,
            cwd=REPO,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
            env={**os.environ, "PYTHONFAULTHANDLER": "1", **(env or {})},
        )
        self.stdout_lines: list[str] = []
        self.stderr_lines: list[str] = []
        self._changed = threading.Condition()
        self.on_stdout = on_stdout
        self._pumps = [
            threading.Thread(target=self._pump, args=(self.process.stdout, self.stdout_lines, True), daemon=True),
            threading.Thread(target=self._pump, args=(self.process.stderr, self.stderr_lines, False), daemon=True),
        ]
        for pump in self._pumps:
            pump.start()

    def _pump(self, stream: Any, lines: list[str], is_stdout: bool) -> None:
        for line in stream:
            if is_stdout and self.on_stdout is not None:
                self.on_stdout(line)
            with self._changed:
                lines.append(line)
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    @property
    def stderr(self) -> str:
        return "".join(self.stderr_lines)

    def wait_for_line(self, pattern: str, timeout: float = 20.0, stream: str = "stderr") -> str:
        """The first line of ``stream`` matching the regular expression ``pattern``; fails after
        ``timeout`` s or when the process ends first (with its stderr)."""
        regex = re.compile(pattern)
        lines = self.stderr_lines if stream == "stderr" else self.stdout_lines
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                for line in lines:
                    if regex.search(line):
                        return line
                if self.process.poll() is not None and not any(p.is_alive() for p in self._pumps):
                    raise AssertionError(
                        f"{' '.join(self.argv)} ended ({self.process.returncode}) before printing /{pattern}/; "
                        f"stderr:\n{self.stderr}"
                    )
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(
                        f"no line /{pattern}/ from {' '.join(self.argv)} in {timeout} s:\n{self.stderr}"
                    )
                self._changed.wait(min(left, 0.2))

    def stop(self, timeout: float = STOP_TIMEOUT_S) -> int:
        """SIGINT, wait; return the exit code (fails the test, after SIGKILL, if it does not end)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise AssertionError(f"{' '.join(self.argv)} did not stop on SIGINT; stderr:\n{self.stderr}") from None
        self._join()
        return code

    def stop_quietly(self) -> list[str]:
        """:meth:`stop` for cleanup: never raises, returns what went wrong."""
        if self.process.poll() is not None:
            self._join()
            return []
        try:
            self.stop()
        except AssertionError:
            return [f"killed {' '.join(self.argv)}: it did not stop on SIGINT"]
        return []

    def _join(self) -> None:
        for pump in self._pumps:
            pump.join(5)
        if self.process.stdin:
            try:
                self.process.stdin.close()
            except OSError:
                pass
