"""The restart policy of ``invent up``'s services, pure (no zenoh, no processes): which policy each
service has (``--restart``), whether a child that ended is started again, and after how long.

As Docker's ``restart: on-failure[:N]``: a service that fails (a non-zero exit or a signal) is
started again after a delay that starts at :attr:`RestartPlan.first_delay_s` and doubles at each
restart in a row, at most :data:`MAX_DELAY_S`, back to the first once the service had run
:data:`STABLE_AFTER_S`; past :attr:`RestartPlan.limit` restarts of one service, it is not started
again (the run ends as without a policy). Exit 0 is no failure, nor is exit 2: a configuration
the service refused would be refused again."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from services.errors import ConfigError
from services.exits import ExitStatus


class RestartPolicy(StrEnum):
    NEVER = "never"
    """A service that ends ends the run (``invent up``'s default)."""
    ON_FAILURE = "on-failure"
    """A service that fails is started again, within the limit, after the backoff."""


MAX_DELAY_S = 60.0
"""The longest delay before a restart (Docker's)."""
STABLE_AFTER_S = 10.0
"""A service that ran this long before it failed has its delay start over (Docker's)."""
DEFAULT_LIMIT = 5
DEFAULT_FIRST_DELAY_S = 0.1
"""The delay before a first restart (Docker's): it doubles at each restart in a row."""
NOT_FAILURES = frozenset({ExitStatus.OK, ExitStatus.CONFIG})
"""A service that ended so is not started again: it ended as it may, or refused its configuration."""


@dataclass(frozen=True)
class History:
    """One service's restarts so far: how many, and the delay before the last (0: none yet)."""

    restarts: int = 0
    delay_s: float = 0.0


@dataclass(frozen=True)
class RestartRule:
    """One service's policy: whether, how often and after how long it is started again."""

    policy: RestartPolicy = RestartPolicy.NEVER
    limit: int = DEFAULT_LIMIT
    first_delay_s: float = DEFAULT_FIRST_DELAY_S

    @staticmethod
    def is_failure(exit_code: int) -> bool:
        """A non-zero exit (a signal: negative) other than a refused configuration's."""
        return exit_code not in NOT_FAILURES

    def next_restart(self, history: History, exit_code: int, ran_s: float) -> History | None:
        """``history`` once the service, ended with ``exit_code`` after running ``ran_s`` wall seconds,
        is started again (its :attr:`History.delay_s` the delay to wait first); None: it is not."""
        if self.policy is RestartPolicy.NEVER or not self.is_failure(exit_code) or history.restarts >= self.limit:
            return None
        in_a_row = history.delay_s > 0 and ran_s < STABLE_AFTER_S
        delay_s = min(history.delay_s * 2, MAX_DELAY_S) if in_a_row else self.first_delay_s
        return History(history.restarts + 1, delay_s)


@dataclass(frozen=True)
class RestartPlan:
    """The run's policies (``--restart``): one for every service, and per service by name."""

    default: RestartPolicy = RestartPolicy.NEVER
    by_service: Mapping[str, RestartPolicy] = field(default_factory=dict)
    limit: int = DEFAULT_LIMIT
    first_delay_s: float = DEFAULT_FIRST_DELAY_S

    def __post_init__(self) -> None:
        if self.limit < 1:
            raise ConfigError(f"--restart-limit {self.limit}: at least 1 restart per service")
        if not (math.isfinite(self.first_delay_s) and 0 < self.first_delay_s <= MAX_DELAY_S):
            raise ConfigError(f"--restart-backoff {self.first_delay_s}: seconds in (0, {MAX_DELAY_S:g}]")

    @property
    def restarts_any(self) -> bool:
        return any(policy is not RestartPolicy.NEVER for policy in (self.default, *self.by_service.values()))

    def rule(self, child: str) -> RestartRule:
        """The rule of ``child`` (as ``up`` names it: ``motor``; in a fleet ``rh0/motor``, a
        per-service policy of ``motor`` applying to every robot's)."""
        policy = self.by_service.get(child.rpartition("/")[2], self.default)
        return RestartRule(policy, self.limit, self.first_delay_s)

    def never(self, services: Collection[str], why: str) -> RestartPlan:
        """The plan with ``services`` never started again; ConfigError naming a ``--restart SERVICE=``
        that asks for one of them, and ``why`` not."""
        for service in sorted(services):
            if self.by_service.get(service, RestartPolicy.NEVER) is not RestartPolicy.NEVER:
                raise ConfigError(f"--restart {service}={self.by_service[service]}: {why}")
        return dataclasses.replace(self, by_service={**self.by_service, **dict.fromkeys(services, RestartPolicy.NEVER)})

    def check_services(self, known: Collection[str]) -> None:
        """ConfigError naming a ``--restart SERVICE=...`` of no service of the run's."""
        unknown = sorted(set(self.by_service) - set(known))
        if unknown:
            raise ConfigError(
                f"--restart {unknown[0]}={self.by_service[unknown[0]]}: no such service in this run "
                f"(one of {', '.join(sorted(known))})"
            )


def parse_restarts(specs: Sequence[str]) -> tuple[RestartPolicy, dict[str, RestartPolicy]]:
    """``--restart POLICY`` (every service) and ``--restart SERVICE=POLICY`` (one, whatever the
    other says), the last given of each winning: the default policy and the per-service ones.
    ConfigError naming the one that is neither."""
    default = RestartPolicy.NEVER
    by_service: dict[str, RestartPolicy] = {}
    for spec in specs:
        service, _, name = spec.rpartition("=")
        try:
            policy = RestartPolicy(name)
        except ValueError:
            choices = ", ".join(RestartPolicy)
            raise ConfigError(f"--restart {spec}: POLICY or SERVICE=POLICY, POLICY one of {choices}") from None
        if "=" in spec and not service:
            raise ConfigError(f"--restart {spec}: SERVICE=POLICY names no service")
        if service:
            by_service[service] = policy
        else:
            default = policy
    return default, by_service
