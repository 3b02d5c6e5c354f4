"""Run ROS 2's own type-description generator on nav2_msgs/action/NavigateToPose, offline, from
the ROS wheels on PyPI, and write (or check) ``nav2_msgs/action/NavigateToPose.json`` beside this
file: the JSON ``rosidl_generator_type_description`` writes for the action and every type derived
from it, with the RIHS01 hashes ROS computes (README.md says where every input came from).

Not part of the test suite: the ROS wheels are built for CPython 3.11 on x86-64 Linux only, and
the suite must not depend on them. Its output is kept in the repository, and
tests/test_ros2_navigate.py compares the hashes the bridge computes with it. Run it again to
check it (or after changing the pins)::

    python3.11 tests/data/ros2_interfaces/generate.py           # rewrite NavigateToPose.json
    python3.11 tests/data/ros2_interfaces/generate.py --check   # exit 1 unless it is unchanged

What it does, as ROS's CMake rule does for a package (rosidl_generator_type_description's
``rosidl_generator_type_description_generate_interfaces.cmake``):

1. a virtual environment with the generator (``ros-rosidl-generator-type-description``,
   ``ros-rosidl-adapter``, ``ros-rosidl-parser``, ``ros-rosidl-pycommon``, Jazzy's 4.6.6);
2. the interface wheels the action depends on, unpacked, each ``share/<pkg>`` an include path
   (``<pkg>:<path>``), where the generator reads the type descriptions of included types;
3. first, a check of the pipeline: the generator run on action_msgs' own ``.idl`` files must give
   the JSON that package ships, byte for byte (and those equal the copies kept here);
4. ``python -m rosidl_adapter`` turns ``NavigateToPose.action`` into ``.idl``, and the generator,
   given the arguments file the CMake rule writes (``package_name``, ``idl_tuples``,
   ``output_dir``, ``include_paths``), writes ``NavigateToPose.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
import venv
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
GENERATOR = (
    "ros-rosidl-generator-type-description==4.6.6",
    "ros-rosidl-adapter==4.6.6",
    "ros-rosidl-parser==4.6.6",
    "ros-rosidl-pycommon==4.6.6",
)
"""ROS 2 Jazzy's rosidl (4.6.6), with what pip resolves for them (empy, lark-parser, rosidl_cli, ...)."""
INTERFACES = {
    "action_msgs": "ros-action-msgs==2.0.3",
    "builtin_interfaces": "ros-builtin-interfaces==2.0.3",
    "service_msgs": "ros-service-msgs==2.0.3",
    "unique_identifier_msgs": "ros-unique-identifier-msgs==2.5.0",
    "geometry_msgs": "ros-geometry-msgs==5.3.6",
    "std_msgs": "ros-std-msgs==5.3.6",
}
"""Jazzy's interface packages the action's types include (rcl_interfaces 2.0.3, common_interfaces 5.3.6)."""
ACTION = HERE / "nav2_msgs" / "action" / "NavigateToPose.action"
OUTPUT = HERE / "nav2_msgs" / "action" / "NavigateToPose.json"
SHIPPED_ACTION_MSGS = ("msg/GoalInfo", "msg/GoalStatus", "msg/GoalStatusArray", "srv/CancelGoal")


def run(*command: str | Path, cwd: Path | None = None) -> None:
    subprocess.run([str(part) for part in command], check=True, cwd=cwd)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def share_directories(python: Path, work: Path) -> dict[str, Path]:
    """Each interface wheel downloaded (no dependencies) and unpacked: its ``share/<pkg>``."""
    wheels = work / "wheels"
    shares = {}
    for package, requirement in INTERFACES.items():
        run(python, "-m", "pip", "download", "--quiet", "--no-deps", "--dest", wheels, requirement)
        (wheel,) = wheels.glob(f"{requirement.split('==')[0].replace('-', '_')}-*.whl")
        print(f"{wheel.name}  sha256 {sha256(wheel)}")
        unpacked = work / "unpacked" / package
        with zipfile.ZipFile(wheel) as archive:
            archive.extractall(unpacked)
        (shares[package],) = unpacked.glob(f"*.data/data/share/{package}")
    return shares


def generate(python: Path, work: Path, package: str, idl_tuples: list[str], shares: dict[str, Path]) -> Path:
    """The generator run as ROS's CMake rule runs it; its output directory."""
    output = work / "generated" / package
    arguments = work / f"{package}__arguments.json"
    arguments.write_text(
        json.dumps(
            {
                "package_name": package,
                "idl_tuples": idl_tuples,
                "output_dir": str(output),
                "include_paths": [f"{name}:{path}" for name, path in shares.items() if name != package],
            }
        )
    )
    run(
        python,
        "-c",
        "import sys; from rosidl_generator_type_description import generate_type_hash; generate_type_hash(sys.argv[1])",
        arguments,
    )
    return output


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare with the kept JSON instead of writing it")
    args = parser.parse_args()
    if sys.version_info[:2] != (3, 11):
        print("the ROS wheels are built for CPython 3.11 only: run this with python3.11", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="rosidl-") as temporary:
        work = Path(temporary)
        venv.EnvBuilder(with_pip=True).create(work / "venv")
        python = work / "venv" / "bin" / "python"
        run(python, "-m", "pip", "install", "--quiet", *GENERATOR)
        shares = share_directories(python, work)

        # 3. The pipeline gives what ROS ships for action_msgs, and the copies here are those.
        shipped = shares["action_msgs"]
        generated = generate(
            python, work, "action_msgs", [f"{shipped}:{name}.idl" for name in SHIPPED_ACTION_MSGS], shares
        )
        for name in SHIPPED_ACTION_MSGS:
            ours = (generated / f"{name}.json").read_bytes()
            if ours != (shipped / f"{name}.json").read_bytes():
                print(f"the generator's action_msgs/{name}.json differs from the one ROS ships", file=sys.stderr)
                return 1
            if ours != (HERE / "action_msgs" / f"{name}.json").read_bytes():
                print(f"action_msgs/{name}.json here differs from the wheel's", file=sys.stderr)
                return 1
        uuid = "msg/UUID.json"
        if (shares["unique_identifier_msgs"] / uuid).read_bytes() != (
            HERE / "unique_identifier_msgs" / uuid
        ).read_bytes():
            print(f"unique_identifier_msgs/{uuid} here differs from the wheel's", file=sys.stderr)
            return 1
        print("the generator reproduces action_msgs' shipped type descriptions byte for byte")

        # 4. NavigateToPose: .action -> .idl -> type description.
        package = work / "nav2_msgs"
        (package / "action").mkdir(parents=True)
        shutil.copy(ACTION, package / "action" / ACTION.name)
        (work / "adapter.json").write_text(json.dumps({"non_idl_tuples": [f"{package}:action/{ACTION.name}"]}))
        run(
            python,
            "-m",
            "rosidl_adapter",
            "--package-name",
            "nav2_msgs",
            "--arguments-file",
            work / "adapter.json",
            "--output-dir",
            work / "idl",
            "--output-file",
            work / "idl_tuples.txt",
        )
        idl_tuples = (work / "idl_tuples.txt").read_text().split()
        description = (generate(python, work, "nav2_msgs", idl_tuples, shares) / "action" / OUTPUT.name).read_bytes()
    if args.check:
        if description != OUTPUT.read_bytes():
            print(f"{OUTPUT.relative_to(HERE)} differs from what the generator writes now", file=sys.stderr)
            return 1
        print(f"{OUTPUT.relative_to(HERE)} is what the generator writes")
        return 0
    OUTPUT.write_bytes(description)
    for entry in json.loads(description)["type_hashes"]:
        print(f"{entry['type_name']}  {entry['hash_string']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
