"""``invent calibrate umbmark``: from return positions measured by hand (the worked example of
docs/odometry.md), its refusals (exit 2 naming the flag or field), and in the simulator with
errors injected in the simulated body, both ways, and none.

The simulated runs use a 1 m square and one run each way (the paper: 4 m, five runs): in lockstep
the runs of one direction end at the same place, and on 1 m the errors the issue names (a wheel
0.3-1 % off, the axle 1-3 %) still move the return positions by 10 cm, against a floor of 1.4 mm
with no error. The three calibrations run at once, each its own process, and the tests share them."""

from __future__ import annotations

import argparse
import json
import math
import subprocess
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader

from services.calibration.benchmark import Benchmark, Conclusion
from services.calibration.umbmark import CONVERGED, Calibration, evaluate
from services.cli.flags import positive_int, positive_length
from services.cli.main import main
from services.config import ConfigError, load_config
from services.recording.calibration import PATHS_TOPIC, RUNS_TOPIC
from services.recording.calibration_report import benchmark_line, summary, write_description
from tests.harness import REPO, invent_command

WORKED_TOML = """\
# the worked example of docs/odometry.md
side = 4.0
cw = [
  { x = -0.112, y = -0.095 },
  { x = -0.097, y = -0.108 },
  { x = -0.105, y = -0.099 },
  { x = -0.090, y = -0.093 },
  { x = -0.096, y = -0.105 },
]
ccw = [
  { x = 0.034, y = -0.027 },
  { x = 0.025, y = -0.036 },
  { x = 0.031, y = -0.029 },
  { x = 0.028, y = -0.030 },
  { x = 0.032, y = -0.028 },
]
"""
WORKED_CSV = """\
direction,x,y
cw,-0.112,-0.095
cw,-0.097,-0.108
cw,-0.105,-0.099
cw,-0.090,-0.093
cw,-0.096,-0.105
ccw,0.034,-0.027
ccw,0.025,-0.036
ccw,0.031,-0.029
ccw,0.028,-0.030
ccw,0.032,-0.028
"""
# Worked by hand (docs/odometry.md): centres of gravity (-0.100, -0.100) and (0.030, -0.030) m;
# α = -0.070/-16 = 0.004375 rad, β = -0.130/-16 = 0.008125 rad, R = 2/sin(0.0040625) = 492.309 m,
# Ed = 492.5295/492.0885 = 1.000896, Eb = 1.570796/1.566421 = 1.002793,
# right 2/(1/Ed + 1) = 1.000448, left 2/(Ed + 1) = 0.999552, E_max,syst = √0.02 = 0.141421 m.
WORKED = {"ed": 1.000896, "eb": 1.002793, "left": 0.999552, "right": 1.000448, "e_max": 0.141421}


@pytest.mark.parametrize(("name", "text"), [("runs.toml", WORKED_TOML), ("runs.csv", WORKED_CSV)])
def test_measured_by_hand_gives_the_worked_example(tmp_path: Path, capsys, name: str, text: str):
    measured = tmp_path / name
    measured.write_text(text)
    output = tmp_path / "calibrated.toml"
    argv = ["calibrate", "umbmark", "--measured", str(measured), "-o", str(output), "--report", str(tmp_path / "r")]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "Ed = D_R/D_L = 1.000896, Eb = b_actual/b_nominal = 1.002793 (1 pass)" in printed
    assert "E_max,syst 141.4 mm (measure again with the corrections applied)" in printed
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["inputs"]["source"] == "measured" and report["inputs"]["side"] == 4.0
    (measured_benchmark,) = report["benchmarks"]
    assert measured_benchmark["centres_of_gravity"]["cw"] == pytest.approx([-0.100, -0.100])
    assert measured_benchmark["centres_of_gravity"]["ccw"] == pytest.approx([0.030, -0.030])
    assert measured_benchmark["alpha"] == pytest.approx(0.004375) and measured_benchmark["beta"] == pytest.approx(
        0.008125
    )
    assert measured_benchmark["radius"] == pytest.approx(492.309, abs=1e-3)
    assert report["ed"] == pytest.approx(WORKED["ed"], abs=1e-6) and report["eb"] == pytest.approx(
        WORKED["eb"], abs=1e-6
    )
    assert report["e_max_syst"] == {
        "before": pytest.approx(WORKED["e_max"], abs=1e-6),
        "after": None,
        "reduction": None,
    }
    corrected = load_config(output).odometry
    assert corrected.left_radius_scale == pytest.approx(WORKED["left"], abs=1e-6)
    assert corrected.right_radius_scale == pytest.approx(WORKED["right"], abs=1e-6)
    assert corrected.axle_scale == pytest.approx(WORKED["eb"], abs=1e-6)
    assert report["corrections"] == pytest.approx(
        {"left_radius_scale": WORKED["left"], "right_radius_scale": WORKED["right"], "axle_scale": WORKED["eb"]},
        abs=1e-6,
    )
    assert (tmp_path / "r" / "umbmark.png").read_bytes().startswith(b"\x89PNG")


def test_the_output_is_the_description_given_with_the_corrections_composed(tmp_path: Path, capsys):
    """A robot already calibrated: the new multipliers are the old ones times the corrections, its
    wheelbase (the calibrated one) is the one the formulas take, and the rest of its file stays."""
    base = tmp_path / "robot.toml"
    base.write_text(
        "[robot]\nname = 'rh7'\nlength_of_axle = 0.5\n\n[odometry]\naxle_scale = 1.01\nleft_radius_scale = 1.002\n\n"
        '[motor]\nmax_vx = "none"\n'
    )
    measured = tmp_path / "runs.toml"
    measured.write_text(WORKED_TOML)
    output = tmp_path / "calibrated.toml"
    argv = ["calibrate", "umbmark", "--config", str(base), "--set", "motor.p_gain_l=3.5", "--measured", str(measured)]
    assert main([*argv, "-o", str(output), "--report", str(tmp_path / "r")]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["benchmarks"][0]["wheelbase"] == pytest.approx(0.5 * 1.01)
    wheelbase = 0.505
    half_beta_sine = math.sin(0.008125 / 2)
    ed = (4.0 + wheelbase * half_beta_sine) / (4.0 - wheelbase * half_beta_sine)
    written = load_config(output)
    assert written.robot.name == "rh7" and written.robot.length_of_axle == 0.5
    assert written.motor.max_vx is None and written.motor.p_gain_l == 3.5
    assert written.odometry.axle_scale == pytest.approx(1.01 * WORKED["eb"], abs=1e-6)
    assert written.odometry.left_radius_scale == pytest.approx(1.002 * 2.0 / (ed + 1.0))
    assert written.odometry.right_radius_scale == pytest.approx(2.0 / (1.0 / ed + 1.0))
    assert output.read_text().startswith("# The robot description with the odometry calibrated by UMBmark")


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (["--sim-set", "motor.p_gain_l=1"], "--sim-set motor.p_gain_l: only the simulated body"),
        (["--sim-set", "robot.radius_of_left_wheel"], "--sim-set 'robot.radius_of_left_wheel' must be KEY=VALUE"),
        (["--sim-set", "robot.radius_of_left_wheel=-0.1"], "--sim-set: "),
        (["--set", "odometry.axle_scale=0"], "axle_scale"),
        (["--measured", "runs.toml", "--runs", "2"], "--runs: --measured computes from a file"),
        (["--measured", "missing.toml"], "--measured missing.toml: No such file or directory"),
        (["--measured", "runs.toml", "--side", "2"], "--side 2 and the side of runs.toml (4 m) differ"),
        (["--measured", "runs.json"], "a .toml or .csv file"),
        (["--measured", "far.csv"], "are they in metres"),
    ],
)
def test_bad_arguments_exit_2_naming_the_flag_or_field(tmp_path: Path, capsys, monkeypatch, flags, named):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs.toml").write_text(WORKED_TOML)
    (tmp_path / "runs.json").write_text("{}")
    (tmp_path / "far.csv").write_text("direction,x,y\ncw,-40,0\nccw,-40,0\n")
    assert main(["calibrate", "umbmark", *flags, "--report", str(tmp_path / "r")]) == 2
    error = capsys.readouterr().err
    assert "invent calibrate: invalid configuration: " in error and named in error
    assert not (tmp_path / "r" / "report.json").exists()


def test_help_explains_the_flags(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "umbmark", "--help"])
    assert exited.value.code == 0
    text = capsys.readouterr().out
    for flag in ("--side", "--runs", "--passes", "--sim-set", "--measured", "--output", "--report", "docs/odometry.md"):
        assert flag in text


@pytest.mark.parametrize("flags", [["--runs", "0"], ["--side", "-4"], ["--passes", "two"]])
def test_bad_numbers_are_refused_by_the_parser(capsys, flags):
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "umbmark", *flags])
    assert exited.value.code == 2
    assert flags[0] in capsys.readouterr().err


def test_the_numbers_flags_take_are_checked_naming_the_text():
    assert positive_length("4") == 4.0 and positive_int("5") == 5
    for parse, text, reason in [
        (positive_length, "0", "'0' must be a positive length in metres"),
        (positive_length, "nan", "'nan' is not finite"),
        (positive_int, "0", "'0' must be at least 1"),
        (positive_int, "1.5", "'1.5' is not a whole number"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=reason):
            parse(text)


FIRST_PASS = Conclusion(
    final=Calibration(1.000002, 0.999998, 1.000241), ed=0.999996, eb=1.000241, e_before=0.0051, e_after=0.00063
)


def test_the_summary_says_the_estimate_the_corrections_and_what_was_written():
    files = {"report": "r/report.json", "figure": "r/umbmark.png"}
    corrections = "odometry.left_radius_scale = 1.000002, odometry.right_radius_scale = 0.999998, "
    assert summary(FIRST_PASS, 1, files) == [
        "estimated: Ed = D_R/D_L = 0.999996, Eb = b_actual/b_nominal = 1.000241 (1 pass)",
        f"corrections: {corrections}odometry.axle_scale = 1.000241",
        "E_max,syst 5.1 mm before, 0.6 mm after: 8.1x smaller",
        "written: r/report.json, r/umbmark.png",
    ]
    measured = Conclusion(final=Calibration(), ed=1.0, eb=1.0, e_before=0.141421, e_after=None)
    lines = summary(measured, 2, files)
    assert lines[0].endswith("(2 passes)")
    assert lines[2] == "E_max,syst 141.4 mm (measure again with the corrections applied)"
    nothing_left = Conclusion(final=Calibration(), ed=1.0, eb=1.0, e_before=0.005, e_after=0.0)
    assert summary(nothing_left, 1, files)[2] == "E_max,syst 5.0 mm before, 0.0 mm after: infx smaller"


def test_a_benchmarks_line_gives_its_centres_of_gravity_and_errors():
    result = evaluate(4.0, 0.441, [(-0.1, -0.1)], [(0.03, -0.03)])
    assert benchmark_line(Benchmark("measured", Calibration(), result)) == (
        "measured: centres of gravity cw (-100.0, -100.0) mm, ccw (+30.0, -30.0) mm; E_max,syst 141.4 mm; "
        f"alpha {result.alpha:+.6f} rad, beta {result.beta:+.6f} rad; Ed {result.ed:.6f}, Eb {result.eb:.6f}"
    )


def test_the_calibrated_description_keeps_the_given_one_and_says_where_it_comes_from(tmp_path: Path):
    output = tmp_path / "calibrated.toml"
    assert write_description(output, {"robot": {"name": "rh7"}}, FIRST_PASS) == output
    lines = output.read_text().splitlines()
    header = "# The robot description with the odometry calibrated by UMBmark (invent calibrate umbmark): "
    assert lines[:2] == [
        f"{header}Ed 0.999996, Eb 1.000241;",
        "# E_max,syst 5.1 mm before, 0.6 mm after. Run the robot with --config FILE.",
    ]
    written = load_config(output)
    assert written.robot.name == "rh7" and written.odometry.axle_scale == 1.000241
    with pytest.raises(ConfigError, match="-o .*: Is a directory"):
        write_description(tmp_path, {}, FIRST_PASS)


SIDE = "1.0"
CASES = {
    # a wheel 0.5 % large and the axle 2 % long; then the other way, 0.5 % small and 2 % short
    "longer": ["robot.radius_of_right_wheel=0.1005", "robot.length_of_axle=0.44982"],
    "shorter": ["robot.radius_of_right_wheel=0.0995", "robot.length_of_axle=0.43218"],
    "none": [],
}


@pytest.fixture(scope="module")
def calibrations(tmp_path_factory) -> dict[str, tuple[subprocess.CompletedProcess[str], dict, Path]]:
    """The three calibrations in the simulator, run at once: (process, report, report directory)."""
    processes = {}
    for name, sim_set in CASES.items():
        directory = tmp_path_factory.mktemp(name)
        argv = ["calibrate", "umbmark", "--side", SIDE, "--runs", "1", "--report", str(directory)]
        argv += ["-o", str(directory / "calibrated.toml"), *(f for value in sim_set for f in ("--sim-set", value))]
        processes[name] = (
            subprocess.Popen(
                invent_command(*argv), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
            ),
            directory,
        )
    results = {}
    for name, (process, directory) in processes.items():
        try:
            output, _ = process.communicate(timeout=240)
        finally:
            if process.poll() is None:
                process.kill()
                process.communicate()
        completed = subprocess.CompletedProcess(process.args, process.returncode, output)
        assert process.returncode == 0, f"{name}:\n{output[-4000:]}"
        results[name] = (completed, json.loads((directory / "report.json").read_text()), directory)
    return results


@pytest.mark.slow
@pytest.mark.parametrize("case", ["longer", "shorter"])
def test_injected_errors_are_found_within_a_fifth_of_their_size(calibrations, case):
    """|Ed − Ed,true| ≤ 0.2 |Ed,true − 1|, the same for Eb; the Eb UMBmark can see is the wheelbase
    over the mean wheel radius (one wheel 0.5 % off moves the mean by 0.25 %), held to it too."""
    _, report, _ = calibrations[case]
    true = report["inputs"]["true_body"]
    right = 0.1005 if case == "longer" else 0.0995
    assert true["ed"] == pytest.approx(right / 0.1) and true["eb"] == pytest.approx(1.02 if case == "longer" else 0.98)
    assert abs(report["ed"] - true["ed"]) <= 0.2 * abs(true["ed"] - 1.0)
    assert abs(report["eb"] - true["eb"]) <= 0.2 * abs(true["eb"] - 1.0)
    seen = true["eb"] / true["mean_radius"]
    assert abs(report["eb"] - seen) <= 0.2 * abs(seen - 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["longer", "shorter"])
def test_the_correction_reduces_the_systematic_error_at_least_tenfold(calibrations, case):
    completed, report, directory = calibrations[case]
    e_max = report["e_max_syst"]
    assert e_max["before"] > 0.05
    assert e_max["after"] <= e_max["before"] / 10.0 and e_max["reduction"] >= 10.0
    assert 1 <= report["passes"] <= 2 and len(report["benchmarks"]) == report["passes"] + 1
    labels = [benchmark["label"] for benchmark in report["benchmarks"]]
    assert labels == ["before", *(f"after pass {n}" for n in range(1, report["passes"] + 1))]
    assert f"({report['passes']} pass" in completed.stdout
    assert report["benchmarks"][-1]["calibration"] == pytest.approx(report["corrections"])
    written = load_config(directory / "calibrated.toml").odometry
    assert (written.left_radius_scale, written.right_radius_scale, written.axle_scale) == pytest.approx(
        tuple(report["corrections"].values())
    )


@pytest.mark.slow
def test_with_no_injected_error_the_corrections_are_one_within_a_thousandth(calibrations):
    _, report, _ = calibrations["none"]
    assert report["inputs"]["true_body"] == {"ed": 1.0, "eb": 1.0, "mean_radius": 1.0}
    assert all(abs(value - 1.0) <= 1e-3 for value in report["corrections"].values()), report["corrections"]
    assert report["passes"] == 1
    assert max(abs(v - 1.0) for v in report["benchmarks"][0]["correction"].values()) < CONVERGED
    e_max = report["e_max_syst"]
    assert e_max["before"] < 0.005 and e_max["after"] <= e_max["before"]


@pytest.mark.slow
def test_the_runs_are_reported_as_they_go_and_left_for_foxglove(calibrations):
    completed, report, directory = calibrations["longer"]
    for direction in ("cw", "ccw"):
        assert f"before: {direction} run 1/1: stopped at (" in completed.stdout
    assert "before: centres of gravity cw (" in completed.stdout and "E_max,syst" in completed.stdout
    runs = [run for benchmark in report["benchmarks"] for run in benchmark["runs"]]
    assert len(runs) == 2 * len(report["benchmarks"])
    for run in runs:
        assert run["error"] == pytest.approx(
            [run["truth_end"][0] - run["odometry_end"][0], run["truth_end"][1] - run["odometry_end"][1]]
        )
        assert math.hypot(*run["odometry_end"]) < 0.01, "the odometry stops where it believes it started"
    assert (directory / "umbmark.png").read_bytes().startswith(b"\x89PNG")
    with (directory / "umbmark.mcap").open("rb") as file:
        messages = [(channel.topic, message) for _, channel, message in make_reader(file).iter_messages()]
    topics = [topic for topic, _ in messages]
    assert topics.count(PATHS_TOPIC) == 1 + len(runs) and topics.count(RUNS_TOPIC) == len(runs)
    scenes = [SceneUpdate.FromString(message.data) for topic, message in messages if topic == PATHS_TOPIC][1:]
    for scene in scenes:
        truth, odometry = scene.entities[0].lines
        assert len(truth.points) > 10 and len(odometry.points) > 10, "each run's path, ground truth and odometry"
    ends = [json.loads(message.data)["truth_end"] for topic, message in messages if topic == RUNS_TOPIC]
    assert ends == [run["truth_end"] for run in runs]
    assert Path(report["inputs"]["scenarios"]["cw"]).read_text().count("[[segments]]") == 2
