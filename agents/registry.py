"""Scenarios and platform kinds by name: what a plug-in registers, what the agent finds.

Both registries (:data:`schemas.scenario.SCENARIOS`, :data:`schemas.platform.PLATFORMS`)
live with the configuration models, which check every name at load; this module is
their typed front for the agents' side, as python-can's ``can.interface`` is for its
``BACKENDS``:

- :func:`register_scenario` (a :class:`~agents.scenarios.Scenario` subclass) and
  :func:`register_platform` (a :class:`~agents.interface.Platform` class with a
  ``kind``) register in this process; an installed distribution declares the same as
  an entry point instead (groups ``fedlab.scenarios`` and ``fedlab.platforms``, value
  ``module:Class``), found when a configuration names it;
- :func:`scenario_class` finds a scenario's class, :func:`platform_kind` a platform spec's
  kind and argument.

Every failure is a :class:`~schemas.registry.RegistryError` (a
:class:`~schemas.base.ConfigError`) naming the name, where it comes from and why.
"""

from __future__ import annotations

from typing import TypeVar

from agents.scenarios.base import Scenario
from schemas.platform import PLATFORMS, PlatformKind
from schemas.platform import platform_kind as platform_kind
from schemas.registry import RegistryError
from schemas.scenario import SCENARIOS

__all__ = [
    "platform_kind",
    "platform_names",
    "register_platform",
    "register_scenario",
    "scenario_class",
    "scenario_names",
]

S = TypeVar("S", bound=type[Scenario])
P = TypeVar("P", bound=PlatformKind)


def register_scenario(cls: S) -> S:
    """Register the scenario ``cls`` under ``cls.name`` (also as a class decorator).

    Raises
    ------
    RegistryError
        Not a :class:`~agents.scenarios.Scenario` subclass, a name that is not a name
        (lowercase letters, digits, - and _), or a name already taken.
    """
    if not (isinstance(cls, type) and issubclass(cls, Scenario)):
        raise RegistryError(f"{cls!r} is not a Scenario subclass (agents.scenarios.Scenario)")
    SCENARIOS.register(cls.name, cls)
    return cls


def register_platform(cls: P) -> P:
    """Register the platform class ``cls`` under ``cls.kind`` (also as a class decorator):
    ``platform = "KIND"`` or ``"KIND:ARGUMENT"`` then builds one with its ``from_spec``.

    Raises
    ------
    RegistryError
        Not a platform class with ``kind``, ``argument``, ``hardware``, ``check_spec``
        and ``from_spec``, or a kind already taken.
    """
    PLATFORMS.register(cls.kind, cls)
    return cls


def scenario_class(kind: str) -> type[Scenario]:
    """The scenario ``kind`` names (RegistryError if none, or not a Scenario subclass)."""
    entry = SCENARIOS.get(kind)
    if not (isinstance(entry, type) and issubclass(entry, Scenario)):
        raise RegistryError(
            f"scenario {kind!r} is {entry!r}, not a Scenario subclass (agents.scenarios)"
        )
    return entry


def scenario_names() -> list[str]:
    """Every scenario known, built in or plugged in (none is imported to list them)."""
    return SCENARIOS.names()


def platform_names() -> list[str]:
    """Every platform kind known (none is imported to list them)."""
    return PLATFORMS.names()
