"""A router's memory through bursts of samples (``python -m benchmarks.burst_memory``; never part of
``make test``): what ``make soak-day`` sees when a burst of hostile input goes through its router.

An ``invent router`` of its own, a client session subscribing a key and another publishing on it;
``--bursts`` bursts of ``--samples`` samples of ``--size`` bytes each, as fast as the publisher puts
them (congestion control BLOCK, so that every sample goes through). After each burst, once the subscriber has every sample, the router's resident memory. Prints a
line a burst and, at the end, the growth at the first burst and over the later ones: a high water
the first burst sets and the later ones stay under is flat; growth at every burst is a leak.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time

import zenoh

from benchmarks.soak import rss_mb
from benchmarks.soak_day import start_router, wait_for
from services.runtime.session import free_port, open_session, session_config

KEY = "invent/burst/memory"
MATCH_TIMEOUT_S = 10.0
DELIVERY_TIMEOUT_S = 30.0


def bursts(count: int, samples: int, size: int) -> list[float]:
    """The router's RSS (MB) before the first burst and after each one."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = start_router(endpoint)
    received = [0]
    lock = threading.Lock()

    def count_sample(_sample: object) -> None:  # a zenoh callback: counts, calls nothing of zenoh's
        with lock:
            received[0] += 1

    try:
        config = session_config(connect=[endpoint], mode="client")
        with open_session(config) as subscriber_session, open_session(config) as publisher_session:
            subscriber_session.declare_subscriber(KEY, count_sample)
            # BLOCK: every sample goes through the router (DROP, zenoh's default, drops most of a
            # burst put this fast: what is measured is the router holding a whole burst)
            publisher = publisher_session.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
            if wait_for(lambda: publisher.matching_status.matching, MATCH_TIMEOUT_S) is None:
                raise RuntimeError(f"no subscriber matched {KEY} within {MATCH_TIMEOUT_S} s")
            payload = bytes(size)
            memory = [rss_mb(router.pid) or 0.0]
            for burst in range(count):
                for _ in range(samples):
                    publisher.put(payload)
                if wait_for(lambda n=burst: received[0] >= (n + 1) * samples, DELIVERY_TIMEOUT_S) is None:
                    raise RuntimeError(f"burst {burst + 1}: {received[0]} of {(burst + 1) * samples} samples arrived")
                memory.append(rss_mb(router.pid) or 0.0)
                print(f"burst {burst + 1}: router {memory[-1]:.1f} MB", flush=True)
            return memory
    finally:
        router.send_signal(signal.SIGINT)
        router.wait(timeout=30)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--bursts", type=int, default=6, help="bursts (default 6)")
    parser.add_argument("--samples", type=int, default=300, help="samples a burst (default 300, as soak-day's)")
    parser.add_argument("--size", type=int, default=40_000, help="bytes a sample (default 40,000: a scan of 8k rays)")
    args = parser.parse_args()
    started = time.monotonic()
    memory = bursts(args.bursts, args.samples, args.size)
    print(
        json.dumps(
            {
                "rss_mb": [round(mb, 1) for mb in memory],
                "first_burst_mb": round(memory[1] - memory[0], 1),
                "later_bursts_mb": round(memory[-1] - memory[1], 2),
                "wall_s": round(time.monotonic() - started, 1),
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
