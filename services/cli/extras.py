"""The optional parts of the install (pyproject.toml's extras) and what a command says when one it
needs is missing: ``pip install .`` is the stack without the simulator's physics, the recordings
and their viewers, and the ROS 2 bridge, so a robot's computer that runs only the motor pulls none of
them. A command that imports a package of an extra not installed exits 2 naming the extra to install."""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import dataclass

from services.exits import ExitStatus


@dataclass(frozen=True)
class Extra:
    name: str
    """As pyproject.toml names it: ``pip install 'invent-zenoh[<name>]'``."""
    brings: str
    """What it brings, as a command needing it says: ``invent sim: needs <brings>``."""
    packages: tuple[str, ...]
    """The top-level packages (as imported) it installs that the project imports."""


SIM = Extra(
    "sim", "the simulator's physics (PyBullet; --engine kinematic runs without it)", ("pybullet", "pybullet_data")
)
VIZ = Extra(
    "viz", "the recordings, plots and viewer (mcap, matplotlib, foxglove-sdk)", ("mcap", "matplotlib", "foxglove")
)
ROS2 = Extra("ros2", "the ROS 2 bridge and bags (rosbags, mcap)", ("rosbags", "mcap"))

EXTRA_OF_PACKAGE = {package: extra for extra in (SIM, ROS2, VIZ) for package in extra.packages}
"""The extra that installs each package (mcap, in two, is [viz]'s: a recording's)."""
EXTRA_OF_COMMAND = {"ros2": ROS2, "export": ROS2}
"""Commands that need an extra whole, checked before they start: ``invent ros2`` uses rosbags only
once it runs (its type hashes, its bags); ``invent export`` reads a recording (mcap) into a bag."""


def missing_extra(command: str | None, error: ModuleNotFoundError) -> Extra | None:
    """The extra whose absence ``error`` is (one of its packages is not installed), or None when it
    is something else, a module missing from an installed package included (a bug: let it be raised)."""
    extra = EXTRA_OF_PACKAGE.get(error.name or "")
    if extra is None:
        return None
    return EXTRA_OF_COMMAND.get(command or "", extra)


def absent_extra(command: str | None) -> Extra | None:
    """The extra ``invent <command>`` needs whole and lacks a package of, if any."""
    extra = EXTRA_OF_COMMAND.get(command or "")
    if extra is None or all(importlib.util.find_spec(package) is not None for package in extra.packages):
        return None
    return extra


def install_hint(extra: Extra) -> str:
    return f"pip install 'invent-zenoh[{extra.name}]'"


def refuse(command: str | None, extra: Extra) -> int:
    """Say which extra ``invent <command>`` needs, on stderr; the exit status to return."""
    print(f"invent {command}: needs {extra.brings}: {install_hint(extra)}", file=sys.stderr)
    return ExitStatus.CONFIG
