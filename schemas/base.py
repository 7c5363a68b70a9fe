"""What every configuration model shares: the base model, the error and the loaders.

A bad value fails at load with the file, the field and the reason::

    ConfigError: deploy/agents/rome.toml: field 'sync_period': Input should be greater than 0

Rule: this module imports no other model module, so :mod:`schemas.config` and
:mod:`schemas.platform` can both build on it without importing each other in a loop.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any, TypeVar

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


def format_validation_error(source: str, error: ValidationError) -> str:
    """One line per problem: ``source: field 'a.b': reason``."""
    lines = []
    for item in error.errors():
        where = ".".join(str(p) for p in item["loc"]) or "(top level)"
        reason = item["msg"]
        if item["type"] == "extra_forbidden":
            reason = "unknown field"
        lines.append(f"{source}: field '{where}': {reason}")
    return "\n".join(lines)


def validate(model: type[M], data: dict[str, Any], source: str) -> M:
    """Build ``model`` from ``data``; a ConfigError names ``source`` and the field."""
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(format_validation_error(source, error)) from None


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
