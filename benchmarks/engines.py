"""The ``engines`` section of ``make bench``: the real-time factor of the lockstep square
(``invent up --scenario square --no-record``, separate processes and ``--composed``) on PyBullet
and on the kinematic engine (``--engine``), in the same bench run, interleaved, and the ratio
kinematic / PyBullet; beside it each engine's own cost per step in-process (the world stepped,
its wheel angles and body pose read and its torques set, in the ``room`` world with the lidar and
the IMU; no scans), which says how much of the loop's step the engine is.

A run's real-time factor is the sim's own: simulated seconds over the wall seconds of its steps,
from the line it logs when the run ends (``finished: N steps, S s simulated in W s``), so the
processes' start-up and shut-down are left out, as the lockstep section's windows leave them out.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from typing import Any

from benchmarks.figures import fmt, median, ratio, timed
from benchmarks.loop import REPO

ENGINES = ("pybullet", "kinematic")
LAYOUTS = ("separate", "composed")
RUN_TIMEOUT_S = 180.0
FINISHED = re.compile(r"finished: (\d+) steps, ([\d.]+) s simulated in ([\d.]+) s")
INPROCESS_WORLD = "room"


def square_real_time_factor(engine: str, composed: bool) -> float:
    """Simulated seconds per wall second of the square's steps on ``engine`` (RuntimeError if the run fails)."""
    argv = [
        sys.executable, "-m", "services.cli", "up", "--scenario", "square", "--mode", "lockstep",
        "--no-record", "--engine", engine, *(["--composed"] if composed else []),
    ]  # fmt: skip
    try:
        result = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired as error:
        raise RuntimeError(f"invent up on {engine} took more than {RUN_TIMEOUT_S:g} s") from error
    output = result.stdout + result.stderr
    found = FINISHED.search(output)
    if result.returncode != 0 or found is None:
        raise RuntimeError(f"invent up on {engine} exited {result.returncode}:\n{output[-2000:]}")
    _steps, simulated, wall = found.groups()
    return float(simulated) / float(wall)


def engine_us_per_step(engine: str, seconds: float) -> float:
    """Wall µs per step of ``engine`` alone, in-process, for about ``seconds``."""
    from services.config import ImuConfig, LidarConfig, RobotConfig, SimConfig, SimEngine
    from sim_bridge.world import load_world

    sim_config = SimConfig(engine=SimEngine(engine))
    world = load_world(INPROCESS_WORLD)
    if sim_config.engine == SimEngine.KINEMATIC:
        from sim_bridge.kinematic import KinematicSimulator

        sim: Any = KinematicSimulator(RobotConfig(), sim_config, world, lidar=LidarConfig(), imu=ImuConfig())
    else:
        from sim_bridge.simulator import Simulator

        sim = Simulator(RobotConfig(), sim_config, world, lidar=LidarConfig(), imu=ImuConfig())
    try:
        robot, steps, started = sim.robots[0], 0, time.perf_counter()
        while (elapsed := time.perf_counter() - started) < seconds:
            for _ in range(500):
                robot.wheel_angles()
                robot.body_pose()
                robot.set_torques([1.0, 1.1] if steps % 2000 < 1000 else [-1.0, -1.1])
                sim.step()
                steps += 1
        return elapsed / steps * 1e6
    finally:
        sim.close()


def run_section(args: argparse.Namespace, failures: list[str]) -> dict[str, Any]:
    factors: dict[str, dict[str, list[float | None]]] = {e: {layout: [] for layout in LAYOUTS} for e in ENGINES}
    costs: dict[str, list[float | None]] = {engine: [] for engine in ENGINES}
    for repeat in range(args.repeats):
        print(f"engines, run {repeat + 1} of {args.repeats}", flush=True)
        for layout in LAYOUTS:
            for engine in ENGINES:
                factors[engine][layout].append(
                    timed(
                        f"the lockstep square on {engine}, {layout}",
                        lambda engine=engine, layout=layout: square_real_time_factor(engine, layout == "composed"),
                        failures,
                    )
                )
        for engine in ENGINES:
            costs[engine].append(
                timed(
                    f"{engine} in-process", lambda engine=engine: engine_us_per_step(engine, args.inprocess), failures
                )
            )
    results: dict[str, Any] = {
        engine: {
            **{f"{layout}_real_time_factor": median(factors[engine][layout]) for layout in LAYOUTS},
            "us_per_step": median(costs[engine]),
        }
        for engine in ENGINES
    }
    results["ratio"] = {
        **{
            layout: ratio(
                results["kinematic"][f"{layout}_real_time_factor"], results["pybullet"][f"{layout}_real_time_factor"]
            )
            for layout in LAYOUTS
        },
        "inprocess": ratio(results["pybullet"]["us_per_step"], results["kinematic"]["us_per_step"]),
    }
    return results


def table(results: dict[str, Any]) -> str:
    """The section as a Markdown table: each engine's figures and kinematic / PyBullet."""
    lines = [
        "| lockstep square | PyBullet | kinematic | kinematic / PyBullet |",
        "|---|---|---|---|",
    ]
    pybullet, kinematic, ratios = results["pybullet"], results["kinematic"], results["ratio"]
    for layout in LAYOUTS:
        field = f"{layout}_real_time_factor"
        lines.append(
            f"| real-time factor, {layout} | {fmt(pybullet[field], 2)}x | {fmt(kinematic[field], 2)}x "
            f"| {fmt(ratios[layout], 2)} |"
        )
    lines.append(
        f"| engine alone, µs per step | {fmt(pybullet['us_per_step'], 1)} | {fmt(kinematic['us_per_step'], 1)} "
        f"| {fmt(ratios['inprocess'], 2)}x faster |"
    )
    return "\n".join(lines)
