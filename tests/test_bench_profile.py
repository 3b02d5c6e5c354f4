"""``make profile``'s summary of py-spy's raw output (benchmarks/profile.py), without py-spy."""

from __future__ import annotations

import os
import threading
import time

from benchmarks.profile import summarise, thread_cpu

RAW = """\
Thread.run (threading.py:1);Node.serve (services/runtime/node.py:300);NodeInput.receive (services/runtime/inputs.py:136) 70
Thread.run (threading.py:1);Node.serve (services/runtime/node.py:300);Publisher.put (services/runtime/inputs.py:59) 20
Thread.run (threading.py:1);Node.serve (services/runtime/node.py:301);MotorCore.step (services/motor/core.py:226) 6
Thread.run (threading.py:1);Node.serve (services/runtime/node.py:301);MotorCore.step (services/motor/core.py:230) 4
not a stack line
"""


def test_waiting_samples_are_counted_but_not_listed_as_work():
    samples, working, leaves, totals = summarise(RAW, top=5)
    assert (samples, working) == (100, 30)
    assert leaves == [("Publisher.put (inputs.py)", 20), ("MotorCore.step (core.py)", 10)], "lines merged by function"
    assert dict(totals)["Node.serve (node.py)"] == 30 and "NodeInput.receive (inputs.py)" not in dict(totals)


def test_thread_cpu_counts_the_cpu_time_of_every_thread_of_a_process():
    burnt, release = threading.Event(), threading.Event()

    def burn() -> None:
        deadline = time.thread_time() + 0.2
        while time.thread_time() < deadline:
            pass
        burnt.set()
        release.wait()

    before = sum(thread_cpu(os.getpid()).values())
    worker = threading.Thread(target=burn)
    worker.start()
    try:
        assert burnt.wait(10)
        after = sum(thread_cpu(os.getpid()).values())
    finally:
        release.set()
        worker.join()
    assert after - before >= 0.1, (before, after)
