"""Kinds found by name: the registry behind scenarios and platform kinds.

A :class:`Registry` maps a name to an object (a scenario class, a platform class) from
three sources, looked up in this order:

1. built-ins: a table of ``"module:attribute"`` (as python-can's ``BACKENDS``), the
   module imported when the name is first looked up;
2. registered in code: :meth:`Registry.register` (a test, or a plug-in module that
   registers itself when it is imported);
3. entry points of the registry's group (``fedlab.scenarios``, ``fedlab.platforms``)
   declared by installed distributions, loaded when their name is looked up.

A name that two sources claim is refused when it is looked up, naming both: which
code drives a platform's valves is never decided by the order distributions happen to
be found in. A name that no source knows, a plug-in that fails to import and an object
that is not what the registry holds each raise :class:`RegistryError` (a
:class:`~schemas.base.ConfigError`) naming the name, the source and why, so a
configuration that names them fails at load.

Rule: pure. Nothing is imported and no distribution is scanned when this module is
imported; a lookup imports the module that defines what it names.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable, Mapping
from importlib import metadata
from typing import Generic, TypeVar

from federation.core.keys import validate_name
from schemas.base import ConfigError

__all__ = ["Registry", "RegistryError"]

T = TypeVar("T")


class RegistryError(ConfigError):
    """A name that cannot be used: unknown, claimed twice, or its code does not load."""


class Registry(Generic[T]):
    """Names of one kind of thing (``what``: "scenario", "platform kind").

    Parameters
    ----------
    what : str
        What a name names, for messages.
    group : str
        The entry-point group plug-ins declare their names in.
    builtins : Mapping[str, str]
        Name -> ``"module:attribute"`` of the kinds that ship with fedlab.
    accept : callable
        ``accept(name, obj)`` returns ``obj`` as the registry's type, or raises
        TypeError saying what it lacks.
    """

    def __init__(
        self,
        what: str,
        group: str,
        builtins: Mapping[str, str],
        accept: Callable[[str, object], T],
    ):
        self.what = what
        self.group = group
        self._builtins = dict(builtins)
        self._accept = accept
        self._registered: dict[str, T] = {}
        self._loaded: dict[str, T] = {}  # built-ins and entry points, once imported
        self._scanned: tuple[tuple[str, ...], dict[str, list[metadata.EntryPoint]]] | None = None

    # -- adding -----------------------------------------------------------------------
    def register(self, name: str, obj: object) -> T:
        """Register ``obj`` under ``name`` in this process; returns it as the registry's type.

        Registering the same object again is allowed (a module imported twice); another
        object under a name already taken (a built-in or a registered one) raises
        :class:`RegistryError`.
        """
        try:
            validate_name(name, f"{self.what} name")
        except ValueError as error:
            raise RegistryError(str(error)) from None
        value = self._checked(name, obj, "registered in code")
        if name in self._builtins:
            raise RegistryError(
                f"{self.what} {name!r} is built in ({self._builtins[name]}): register "
                "yours under another name"
            )
        known = self._registered.get(name)
        if known is not None and known is not value:
            raise RegistryError(
                f"{self.what} {name!r} is already registered ({_describe(known)}), "
                f"not {_describe(value)}"
            )
        self._registered[name] = value
        return value

    def unregister(self, name: str) -> None:
        """Forget a name registered in code (tests); built-ins and entry points stay."""
        self._registered.pop(name, None)

    # -- finding ----------------------------------------------------------------------
    def __contains__(self, name: object) -> bool:
        """Whether ``name`` is known (nothing is imported to tell)."""
        if not isinstance(name, str):
            return False
        return name in self._builtins or name in self._registered or name in self._entry_points()

    def names(self) -> list[str]:
        """Every known name, sorted (nothing is imported to list them)."""
        return sorted({*self._builtins, *self._registered, *self._entry_points()})

    def get(self, name: str) -> T:
        """What ``name`` names.

        Raises
        ------
        RegistryError
            An unknown name (the message lists the known ones), a name claimed twice, a
            plug-in that fails to import, or an object that is not a valid entry.
        """
        loaded = self._loaded.get(name)
        if loaded is not None:
            return loaded
        points = self._entry_points().get(name, [])
        builtin = self._builtins.get(name)
        claims = [] if builtin is None else [f"built in ({builtin})"]
        same = {builtin}
        if name in self._registered:
            target = _describe(self._registered[name])
            claims.append(f"registered in code ({target})")
            same.add(target)
        # An entry point naming the object already claimed (a plug-in module that also
        # registers itself when imported) is the same claim, not another.
        claims += [_entry_point_source(p) for p in points if p.value not in same]
        if len(claims) > 1:
            raise RegistryError(
                f"{self.what} {name!r} is claimed {len(claims)} times: {'; '.join(claims)} "
                "(uninstall or rename all but one)"
            )
        if builtin is not None:
            value = self._checked(name, _load(builtin, f"built-in {self.what} {name!r}"), builtin)
            self._loaded[name] = value
            return value
        if name in self._registered:
            return self._registered[name]
        if points:
            source = _entry_point_source(points[0])
            try:
                obj = points[0].load()
            except Exception as error:  # any import-time failure of third-party code
                raise RegistryError(
                    f"{self.what} {name!r}: {source} does not load: {type(error).__name__}: {error}"
                ) from error
            value = self._checked(name, obj, source)
            self._loaded[name] = value
            return value
        known = ", ".join(self.names()) or "none"
        raise RegistryError(f"unknown {self.what} {name!r} (known: {known})")

    def _checked(self, name: str, obj: object, source: str) -> T:
        try:
            return self._accept(name, obj)
        except TypeError as error:
            raise RegistryError(f"{self.what} {name!r} ({source}): {error}") from None

    def _entry_points(self) -> dict[str, list[metadata.EntryPoint]]:
        """The group's entry points by name, scanned again when ``sys.path`` changes."""
        key = tuple(sys.path)
        if self._scanned is None or self._scanned[0] != key:
            found: dict[str, list[metadata.EntryPoint]] = {}
            for point in _unique(metadata.entry_points(group=self.group)):
                found.setdefault(point.name, []).append(point)
            self._scanned = (key, found)
        return self._scanned[1]


def _unique(points: Iterable[metadata.EntryPoint]) -> list[metadata.EntryPoint]:
    """One of each (name, value): a distribution found twice on the path is one claim."""
    seen: dict[tuple[str, str], metadata.EntryPoint] = {}
    for point in points:
        seen.setdefault((point.name, point.value), point)
    return list(seen.values())


def _entry_point_source(point: metadata.EntryPoint) -> str:
    dist = point.dist
    owner = "an unnamed distribution" if dist is None else f"distribution {dist.name!r}"
    return f"entry point {point.value} of {owner}"


def _describe(obj: object) -> str:
    module = getattr(obj, "__module__", None)
    name = getattr(obj, "__qualname__", None) or type(obj).__qualname__
    return f"{module}:{name}" if module else name


def _load(target: str, what: str) -> object:
    """The object ``module:attribute`` names."""
    module_name, _, attribute = target.partition(":")
    try:
        module = importlib.import_module(module_name)
        obj: object = module
        for part in attribute.split(".") if attribute else ():
            obj = getattr(obj, part)
    except Exception as error:  # a broken install: say which module, and why
        raise RegistryError(
            f"{what}: {target} does not load: {type(error).__name__}: {error}"
        ) from error
    return obj
