"""``FILE.py:NAME``: a user service's class loaded from its file, and its declarations checked
(its name, the queryables it calls, its lockstep, whether it drives), before anything runs. A bad one is a
:class:`~services.errors.ConfigError` naming the file and what is wrong: exit 2."""

from __future__ import annotations

import importlib.util
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from schemas.keys import Keys, Service, UserServiceName, user_service_name, validate_own_key
from services import interfaces
from services.config import Config
from services.errors import ConfigError
from services.extension.api import Drives, Lockstep, UserService

DeclarationT = TypeVar("DeclarationT", Lockstep, Drives)


@dataclass(frozen=True)
class Loaded:
    """A user service as the launcher and the runner see it: where it came from and its class."""

    spec: str
    """``FILE.py:NAME`` as given."""
    service: type[UserService]
    name: UserServiceName


def split_spec(spec: str) -> tuple[Path, str]:
    """``FILE.py:NAME`` -> (the file, the class's name); ConfigError when it is not of that form."""
    path, colon, attribute = spec.rpartition(":")
    if not colon or not path.endswith(".py") or not attribute.isidentifier():
        raise ConfigError(f"{spec}: a user service is FILE.py:NAME (a Python file, then the class's name)")
    return Path(path), attribute


def load(spec: str) -> Loaded:
    """Import ``FILE.py`` (as a module of its own, once per process) and check its class ``NAME``."""
    path, attribute = split_spec(spec)
    if not path.is_file():
        raise ConfigError(f"{spec}: no such file {path}")
    module_name = f"invent_user_service_{abs(hash(str(path.resolve())))}"
    module = sys.modules.get(module_name)
    if module is None:
        module_spec = importlib.util.spec_from_file_location(module_name, path)
        if module_spec is None or module_spec.loader is None:
            raise ConfigError(f"{spec}: {path} cannot be imported as Python")
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[module_name] = module  # before it runs: a dataclass of the file looks its module up
        try:
            module_spec.loader.exec_module(module)
        except Exception as error:  # noqa: BLE001 (any error in the user's file is the file's, named)
            del sys.modules[module_name]
            raise ConfigError(f"{spec}: importing {path} failed: {type(error).__name__}: {error}") from None
    service = getattr(module, attribute, None)
    if service is None:
        raise ConfigError(f"{spec}: {path} defines no {attribute}")
    if not (isinstance(service, type) and issubclass(service, UserService)) or service is UserService:
        raise ConfigError(f"{spec}: {attribute} is not a subclass of services.extension.api.UserService")
    return Loaded(spec, service, check_declarations(spec, service))


def check_declarations(spec: str, service: type[UserService]) -> UserServiceName:
    """Its name, calls, lockstep and drives as the class declares them; ConfigError naming the first wrong one."""
    name = getattr(service, "name", None)
    if not isinstance(name, str):
        raise ConfigError(f"{spec}: {service.__name__}.name must be set to the service's name (a str)")
    for attribute in ("reads", "calls"):
        declared = getattr(service, attribute)
        if not isinstance(declared, tuple) or not all(isinstance(key, str) for key in declared):
            raise ConfigError(f"{spec}: {service.__name__}.{attribute} must be a tuple of keys (str), got {declared!r}")
    try:
        checked = user_service_name(name)
        for key in (*service.reads, *service.calls):
            validate_own_key(key)
    except ValueError as error:
        raise ConfigError(f"{spec}: {error}") from None
    lockstep = _declared(spec, service, "lockstep", Lockstep, "Lockstep(output, rate_hz)")
    if lockstep is not None:
        try:
            validate_own_key(lockstep.output)
        except ValueError as error:
            raise ConfigError(f"{spec}: lockstep.output: {error}") from None
    drives = _declared(spec, service, "drives", Drives, "Drives(rate_hz)")
    # it runs as the drive, with exactly the drive's rights: no keys, queryables or calls of its own
    if drives is not None and (lockstep is not None or service.calls):
        what = "lockstep" if lockstep is not None else "calls"
        raise ConfigError(
            f"{spec}: {service.__name__}.drives with {what}: a service that drives is the drive's participant and has the drive's rights only"
        )
    if drives is not None:
        _reads_as_the_drive(spec, service)
    return checked


def _reads_as_the_drive(spec: str, service: type[UserService]) -> None:
    """A service that drives connects as the drive: it may read only what the drive declares it subscribes."""
    keys = Keys()
    drive = interfaces.declared(Service.DRIVE, keys, Config()).subscribes
    beyond = [key for key in service.reads if f"{keys.prefix}/{key}" not in drive]
    if beyond:
        allowed = ", ".join(key.removeprefix(f"{keys.prefix}/") for key in drive)
        raise ConfigError(
            f"{spec}: {service.__name__}.reads {', '.join(beyond)}: a service that drives has the drive's rights, "
            f"and the drive reads only {allowed}"
        )


def _declared(
    spec: str, service: type[UserService], attribute: str, kind: type[DeclarationT], form: str
) -> DeclarationT | None:
    """``service.<attribute>``: None, or a ``kind`` with a finite rate > 0; ConfigError otherwise."""
    declared = getattr(service, attribute)
    if declared is None:
        return None
    if not isinstance(declared, kind):
        raise ConfigError(f"{spec}: {service.__name__}.{attribute} must be a {form} or None")
    rate_hz = declared.rate_hz
    if not (isinstance(rate_hz, int | float) and math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"{spec}: {attribute}.rate_hz must be a finite number > 0, got {rate_hz!r}")
    return declared


def driving(loaded: Sequence[Loaded]) -> Loaded | None:
    """The one of ``loaded`` that drives, if any; ConfigError naming both when two do."""
    drivers = [one for one in loaded if one.service.drives is not None]
    if len(drivers) > 1:
        raise ConfigError(f"{drivers[0].spec} and {drivers[1].spec} both drive: one velocity source per robot")
    return drivers[0] if drivers else None


def load_all(specs: Sequence[str], taken: Sequence[str] = ()) -> tuple[Loaded, ...]:
    """Every ``--with`` of a run, loaded; ConfigError for two of the same name (or a name in ``taken``)."""
    loaded: list[Loaded] = []
    for spec in specs:
        one = load(spec)
        clash = next((other.spec for other in loaded if other.name == one.name), None)
        if clash is not None or one.name in taken:
            raise ConfigError(f"{spec}: the name {one.name!r} is taken already ({clash or 'in this run'})")
        loaded.append(one)
    return tuple(loaded)
