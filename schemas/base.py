"""What every configuration model shares: the base model, the error and the loaders.

A bad value fails at load with the file, the field and the reason::

    ConfigError: deploy/agents/rome.toml: field 'sync_period': Input should be greater than 0

Rule: this module imports no other model module, so :mod:`schemas.config` and
:mod:`schemas.platform` can both build on it without importing each other in a loop.
"""

from __future__ import annotations

import difflib
import json
import tomllib
import types
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar, Union, get_args, get_origin

from pydantic import AfterValidator, BaseModel, ConfigDict, ValidationError

from federation.core.keys import validate_lab, validate_name

__all__ = ["ConfigError", "Model", "format_validation_error", "load_model", "name", "validate"]


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names where and why."""


def name(what: str) -> AfterValidator:
    """A validator of a name (lab, agent, platform ...): lowercase letters, digits, - and _."""
    return AfterValidator(lambda v: validate_name(v, what))


LAB_NAME = AfterValidator(validate_lab)
"""A validator of a lab's name: a name (:func:`name`), and not a reserved one."""


class Model(BaseModel):
    """Frozen, an unknown field is an error (a typo never passes silently), and no number
    is infinite or NaN (a gain of ``inf`` or a noise of ``nan`` would reach the valves)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


M = TypeVar("M", bound=BaseModel)


def format_validation_error(
    source: str, error: ValidationError, model: type[BaseModel] | None = None
) -> str:
    """One line per problem: ``source: field 'a.b': reason``. Given the ``model`` that
    was validated, an unknown field names the closest known one (``did you mean``)."""
    lines = []
    for item in error.errors():
        where = ".".join(str(p) for p in item["loc"]) or "(top level)"
        reason = item["msg"]
        if item["type"] == "extra_forbidden":
            reason = "unknown field"
            if model is not None:
                reason += _hint(item["loc"], known_fields(model, item["loc"][:-1]))
        lines.append(f"{source}: field '{where}': {reason}")
    return "\n".join(lines)


def _hint(loc: Sequence[int | str], known: set[str]) -> str:
    """`` (did you mean 'x'?)`` for the known field closest to ``loc``'s last part; when
    none is close, the few known ones; nothing when they are many or unknown."""
    close = difflib.get_close_matches(str(loc[-1]), sorted(known), n=1, cutoff=0.6)
    if close:
        return f" (did you mean '{close[0]}'?)"
    if 0 < len(known) <= 12:
        return f" (known here: {', '.join(sorted(known))})"
    return ""


def known_fields(model: type[BaseModel], path: Sequence[int | str]) -> set[str]:
    """The field names a table at ``path`` (a validation error's location) in ``model``
    may hold: each model's along the path, through dicts, lists, optionals and unions
    (of a union, every member's). A part naming none (a union member's tag) is passed."""
    kinds: list[Any] = [model]
    for part in path:
        stepped = [t for kind in kinds for t in _step(kind, part)]
        kinds = stepped or kinds
    return {name for kind in kinds for name in _models_fields(kind)}


def _flat(kind: Any) -> list[Any]:
    """``kind`` without Annotated, a union as its members."""
    origin = get_origin(kind)
    if origin is Annotated:
        return _flat(get_args(kind)[0])
    if origin is Union or origin is types.UnionType:
        return [m for arg in get_args(kind) for m in _flat(arg)]
    return [kind]


def _step(kind: Any, part: int | str) -> list[Any]:
    out: list[Any] = []
    for member in _flat(kind):
        origin, args = get_origin(member), get_args(member)
        if isinstance(member, type) and issubclass(member, BaseModel):
            if part == member.__name__:
                out.append(member)
            elif isinstance(part, str) and part in member.model_fields:
                out.append(member.model_fields[part].annotation)
        elif origin is dict and len(args) == 2 and isinstance(part, str):
            out.append(args[1])
        elif origin in (list, tuple, set, frozenset) and args and isinstance(part, int):
            out.append(args[0])
    return out


def _models_fields(kind: Any) -> set[str]:
    return {
        name
        for member in _flat(kind)
        if isinstance(member, type) and issubclass(member, BaseModel)
        for name in member.model_fields
    }


def validate(model: type[M], data: dict[str, Any], source: str) -> M:
    """Build ``model`` from ``data``; a ConfigError names ``source`` and the field."""
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(format_validation_error(source, error, model)) from None


def load_model(model: type[M], path: str | Path) -> M:
    """Load a TOML or JSON file into ``model``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ConfigError(f"{path}: cannot read: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not UTF-8 text (byte {error.start}): {error.reason}") from None
    try:
        data = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
    except (ValueError, tomllib.TOMLDecodeError) as error:
        raise ConfigError(
            f"{path}: not valid {'JSON' if path.suffix == '.json' else 'TOML'}: {error}"
        ) from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a table of fields at the top level")
    return validate(model, data, str(path))
