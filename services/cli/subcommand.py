"""What a module of ``services/cli/`` that is one ``invent`` subcommand (not a service) holds:
its help, the shared flag groups it takes, its own flags and its run. The subcommand is named as
its module is; services/cli/main.py assembles them (a service's is
:class:`services.cli.serve.ServiceCli`)."""

from __future__ import annotations

import argparse
from typing import Protocol


class SubcommandModule(Protocol):
    __name__: str
    """The module's, ``services.cli.<subcommand>``: the subcommand's name is its last part."""
    HELP: str
    """One line in ``invent --help``."""
    DESCRIPTION: str
    """The text of ``invent <subcommand> --help``."""
    GROUPS: tuple[str, ...]
    """The shared flag groups it takes (:class:`services.cli.flags.Parents`' attributes)."""

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Adds its own flags to its parser."""

    def run(self, args: argparse.Namespace) -> int:
        """Does what it is asked; its exit status."""
