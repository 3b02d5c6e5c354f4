"""Lockstep means deterministic with goals: a run of goals sent at fixed simulation times
(``--goals --goal-file``), a goal navigated around a U (plans and costmaps), and a seeded particle
filter each give the same samples, quiet and beside two CPU-burning processes (tests/test_determinism.py:
the square, and how the runs are recorded from outside).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from schemas.codec import decode
from schemas.messages import ScenarioOutcome, TimedDoubleSeq, TimedPosition
from schemas.navigation import GoalPlan, GoalTarget
from services.config import GoalsConfig
from tests.harness import (
    REPO,
    run_invent,
)
from tests.test_determinism import (
    BURNERS,
    KEYS,
    SquareRun,
    _assert_loaded,
    _assert_same_samples,
    _burning_cpus,
    _run,
)

pytestmark = pytest.mark.slow


def _quiet_and_loaded(base: Path, recorded: tuple[str, ...], *flags: str) -> dict[str, SquareRun]:
    """The same run on a quiet machine, then beside :data:`BURNERS` CPU-burning processes."""
    quiet = _run(base / "quiet", recorded, *flags)
    with _burning_cpus(BURNERS) as burner_shares:
        loaded = _run(base / "loaded", recorded, *flags)
    loaded.burner_shares = burner_shares
    return {"quiet": quiet, "loaded": loaded}


GOAL_FILE = REPO / "examples" / "goals" / "errands.toml"
GOAL_RECORDED = (
    KEYS.sim_body_pose,
    KEYS.odometry_pose,
    KEYS.drive_target_velocity,
    KEYS.drive_goal,
    KEYS.drive_goal_feedback,
    KEYS.drive_outcome,
    KEYS.drive_plan,
)


@pytest.fixture(scope="module")
def goal_runs(tmp_path_factory) -> dict[str, SquareRun]:
    """``examples/goals/errands.toml`` (a goal, one preempting it, a cancel, a goal in ``odom``)
    sent by the drive at fixed simulation times, through the same path as ``drive/goal/send``, in
    lockstep: on a quiet machine and beside two CPU burners. Composed (the square's runs in
    tests/test_determinism.py show composed and separate processes give the same samples): the pair
    takes seconds, not half a minute."""
    return _quiet_and_loaded(
        tmp_path_factory.mktemp("goals"), GOAL_RECORDED, "--goals", "--goal-file", str(GOAL_FILE), "--composed"
    )


def test_goals_sent_at_fixed_simulation_times_end_the_same_on_a_quiet_and_a_loaded_machine(goal_runs):
    quiet, loaded = goal_runs["quiet"], goal_runs["loaded"]
    outcomes = [decode(ScenarioOutcome, sample) for sample in quiet.samples[KEYS.drive_outcome]]
    assert [(o.goal_id, o.outcome) for o in outcomes] == [
        ("g1", "canceled"),
        ("corner", "canceled"),
        ("g2", "completed"),
    ], quiet.output[-4000:]
    assert outcomes[0].reason == "preempted by goal 'corner'"
    assert quiet.returncode == 0, "the last goal completed: exit 0"
    home = decode(TimedDoubleSeq, quiet.samples[KEYS.sim_body_pose][-1]).data
    assert math.hypot(home[0], home[1]) <= GoalsConfig().position_tolerance, "the ground truth at the last goal"
    assert [decode(GoalTarget, sample).id for sample in quiet.samples[KEYS.drive_goal]] == ["g1", "corner", "g2"]
    assert loaded.returncode == quiet.returncode, loaded.output[-4000:]
    _assert_same_samples(quiet, loaded)
    _assert_loaded(loaded)


DETOUR_GOAL_FILE = REPO / "examples" / "goals" / "u_trap.toml"
DETOUR_RECORDED = (
    KEYS.sim_body_pose,
    KEYS.sim_scan,
    KEYS.drive_target_velocity,
    KEYS.drive_plan,
    KEYS.drive_costmap,
    KEYS.drive_outcome,
)


@pytest.fixture(scope="module")
def detour_runs(tmp_path_factory) -> dict[str, SquareRun]:
    """``examples/goals/u_trap.toml``: a goal behind a U across the straight line, navigated (the lidar's
    costmap, plans replaced as the U comes into view), composed on the kinematic engine (the navigation
    is the point): quiet, then beside two CPU burners."""
    flags = ("--goal-file", str(DETOUR_GOAL_FILE), "--composed", "--engine", "kinematic", "--set", "sim.world=u_trap")
    return _quiet_and_loaded(tmp_path_factory.mktemp("detour"), DETOUR_RECORDED, *flags)


def test_a_goal_navigated_around_a_u_gives_the_same_plans_costmaps_and_outcome_quiet_and_loaded(detour_runs):
    quiet, loaded = detour_runs["quiet"], detour_runs["loaded"]
    (outcome,) = [decode(ScenarioOutcome, sample) for sample in quiet.samples[KEYS.drive_outcome]]
    assert outcome.outcome == "completed" and quiet.returncode == 0, quiet.output[-4000:]
    plans = [decode(GoalPlan, sample) for sample in quiet.samples[KEYS.drive_plan]]
    assert len(plans) >= 2, "replanned as the U came into view"
    assert any(abs(y) > 1.1 for plan in plans for _x, y in plan.points), "a plan round an arm of the U"
    assert plans[-1].points == [], "the plan cleared as the goal ended"
    assert loaded.returncode == quiet.returncode, loaded.output[-4000:]
    _assert_same_samples(quiet, loaded)
    _assert_loaded(loaded)


AMCL_RECORDED = (
    KEYS.sim_body_pose,
    KEYS.localization_pose,
    KEYS.localization_particles,
    KEYS.odometry_pose,
    KEYS.drive_target_velocity,
    KEYS.drive_outcome,
)


@pytest.fixture(scope="module")
def amcl_runs(tmp_path_factory) -> dict[str, SquareRun]:
    """The goal round the U again, localized by the particle filter on the world's map (seeded, the
    lidar noisy, the fixes at the lidar's rate): quiet, then beside two CPU burners."""
    base = tmp_path_factory.mktemp("amcl")
    map_file = base / "u_trap.yaml"
    made = run_invent("map", "--world", "u_trap", "-o", str(map_file))
    assert made.returncode == 0, made.stderr
    flags = (
        *("--goal-file", str(DETOUR_GOAL_FILE), "--composed", "--engine", "kinematic", "--set", "sim.world=u_trap"),
        *("--map", str(map_file), "--set", "localization.mode=amcl", "--set", "localization.seed=3"),
        *("--set", "localization.rate=10", "--set", "lidar.noise=0.01", "--set", "lidar.seed=5"),
    )
    return _quiet_and_loaded(base, AMCL_RECORDED, *flags)


def test_a_seeded_particle_filter_gives_the_same_estimates_quiet_and_loaded(amcl_runs):
    quiet, loaded = amcl_runs["quiet"], amcl_runs["loaded"]
    assert quiet.returncode == 0, quiet.output[-4000:]
    estimates = [decode(TimedPosition, sample) for sample in quiet.samples[KEYS.localization_pose]]
    assert len(estimates) > 100 and all(len(estimate.error) == 6 for estimate in estimates), "amcl's, with covariance"
    assert quiet.samples[KEYS.localization_particles], "the particles were published"
    assert loaded.returncode == quiet.returncode, loaded.output[-4000:]
    _assert_same_samples(quiet, loaded)
    _assert_loaded(loaded)
