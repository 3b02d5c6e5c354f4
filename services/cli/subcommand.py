"""What an ``invent`` subcommand that is not a service is to the parser (services/cli/main.py
assembles them; a service's is :class:`services.cli.serve.ServiceCli`)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Subcommand:
    name: str
    help: str
    description: str
    groups: tuple[str, ...]
    """The shared flag groups it takes (:class:`services.cli.flags.Parents`' attributes)."""
    add_arguments: Callable[[argparse.ArgumentParser], None]
    """Adds its own flags to its parser."""
    run: Callable[[argparse.Namespace], int]
    """Does what it is asked; its exit status."""
