"""The hostile bursts ``make soak-day`` sends (benchmarks/soak_day.py): payloads drawn from
tests/hostile_payloads.py's strategies before the day starts, less the cancels a running errand would
obey."""

from __future__ import annotations

from dataclasses import dataclass

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from schemas.codec import BadMessage, decode
from schemas.navigation import CancelRequest
from tests.hostile_payloads import cancel_requests, goal_requests, scans

HOSTILE_PER_KEY = 300


def draw_payloads(strategy: st.SearchStrategy[bytes], count: int) -> list[bytes]:
    """``count`` payloads of a hypothesis strategy, no database, no shrinking."""
    drawn: list[bytes] = []

    @settings(
        max_examples=count,
        database=None,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
        deadline=None,
    )
    @given(strategy)
    def collect(payload: bytes) -> None:
        drawn.append(payload)

    collect()
    return drawn[:count]


def cancels_whatever_runs(payload: bytes) -> bool:
    """A cancel the drive obeys while an errand runs (refused by ``make fuzz`` while none does): an
    empty payload, or one that decodes with no id, however it is spelled."""
    if not payload.strip():
        return True
    try:
        return decode(CancelRequest, payload).id == ""
    except BadMessage:
        return False


def bad_cancels() -> st.SearchStrategy[bytes]:
    """The hostile cancels that are refused whatever runs."""
    return cancel_requests().filter(lambda payload: not cancels_whatever_runs(payload))


@dataclass
class Burst:
    """One burst's hostile payloads, drawn before the day starts."""

    goals: list[bytes]
    cancels: list[bytes]
    scans: list[bytes]


def draw_bursts(count: int) -> list[Burst]:
    return [
        Burst(
            draw_payloads(goal_requests(), HOSTILE_PER_KEY),
            draw_payloads(bad_cancels(), HOSTILE_PER_KEY),
            draw_payloads(scans(), HOSTILE_PER_KEY),
        )
        for _ in range(count)
    ]
