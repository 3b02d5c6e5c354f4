"""``invent localization``: its flags, each the override of a ``localization.*`` config key."""

from __future__ import annotations

import argparse
from typing import Any

from services.cli.serve import ServiceCli, no_options
from services.config import LocalizationConfig
from services.localization.service import COMMAND

TRIPLES = {"noise": ("noise_x", "noise_y", "noise_theta"), "initial": ("initial_x", "initial_y", "initial_theta")}
"""The flags of three numbers, and the config keys they set in order."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = LocalizationConfig()
    group = parser.add_argument_group("localization (each flag overrides its localization.* config key)")
    group.add_argument(
        "--rate", type=float, metavar="HZ", help=f"fixes per second of simulation time (default {defaults.rate:g})"
    )
    _triple_flag(
        group, "noise", ("SX", "SY", "STHETA"), "standard deviations of the Gaussian noise on x, y (m) and theta (rad)"
    )
    group.add_argument("--seed", type=int, metavar="N", help="random seed of the noise (default: from the OS)")
    _triple_flag(group, "initial", ("X", "Y", "THETA"), "initial pose published before the first fix")


def _triple_flag(group: argparse._ArgumentGroup, flag: str, metavar: tuple[str, str, str], what: str) -> None:
    """``--<flag> A B C``: the three ``localization.*`` keys of ``TRIPLES[flag]`` at once."""
    defaults = LocalizationConfig()
    default = " ".join(f"{getattr(defaults, key):g}" for key in TRIPLES[flag])
    group.add_argument(f"--{flag}", type=float, nargs=3, metavar=metavar, help=f"{what} (default {default})")


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    keys = {"localization.rate": args.rate, "localization.seed": args.seed}
    for flag, names in TRIPLES.items():
        values = getattr(args, flag) or (None, None, None)
        keys.update({f"localization.{name}": value for name, value in zip(names, values, strict=True)})
    return keys


CLI = ServiceCli(
    command=COMMAND,
    help="the localization stub: initial pose, then noisy fixes of the simulated pose (sim time)",
    description="Publish localization/pose: the initial pose (localization.initial_*), then every "
    "1/rate seconds of simulation time the latest motor/sim_pose/localization plus Gaussian noise "
    "(localization.noise_*, seeded by localization.seed). See docs/localization.md.",
    add_arguments=add_arguments,
    options=no_options,
    overrides=overrides,
)
