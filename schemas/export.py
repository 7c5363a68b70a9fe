"""Export the JSON Schemas of fedlab's messages and configuration files.

Writes ``schemas/json/<Name>.schema.json`` (JSON Schema draft 2020-12, from pydantic's
``model_json_schema()``) for every model in :data:`MODELS`, so a client written in
another language can validate what it publishes and reads without Python::

    python -m schemas.export            # (re)write schemas/json/
    python -m schemas.export --check    # exit 1 if the files on disk differ from the models

The files are committed; ``tests/test_schemas_export.py`` fails when a model changes
and the files were not regenerated.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from schemas.config import AgentConfig, RouterConfig
from schemas.experiment import ExperimentConfig
from schemas.messages import Command, PeerStatus, Status
from schemas.platform import PlatformConfig

__all__ = ["CONFIGS", "DEFAULT_DIR", "MESSAGES", "MODELS", "check", "export", "main", "render"]

MESSAGES: tuple[type[BaseModel], ...] = (Status, PeerStatus, Command)
"""What agents put on the wire as JSON (``.../status``, ``fedlab/<federation>/control``)."""

CONFIGS: tuple[type[BaseModel], ...] = (
    AgentConfig,
    RouterConfig,
    ExperimentConfig,
    PlatformConfig,
)
"""What operators write: agent, router, experiment and platform files."""

MODELS = MESSAGES + CONFIGS

DEFAULT_DIR = Path(__file__).resolve().parent / "json"
_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def file_name(model: type[BaseModel]) -> str:
    """``<Name>.schema.json``."""
    return f"{model.__name__}.schema.json"


def render(model: type[BaseModel]) -> str:
    """The schema file's text: stable key order, two-space indent, final newline."""
    schema: dict[str, Any] = {"$schema": _DIALECT, **model.model_json_schema()}
    return json.dumps(schema, indent=2, ensure_ascii=False) + "\n"


def export(out_dir: Path = DEFAULT_DIR) -> list[Path]:
    """Write every model's schema into ``out_dir``; returns the files written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for model in MODELS:
        path = out_dir / file_name(model)
        path.write_text(render(model), encoding="utf-8")
        written.append(path)
    return written


def check(out_dir: Path = DEFAULT_DIR) -> list[str]:
    """Names of the schema files in ``out_dir`` that are missing or differ from the models."""
    stale = []
    for model in MODELS:
        path = out_dir / file_name(model)
        if not path.exists() or path.read_text(encoding="utf-8") != render(model):
            stale.append(path.name)
    return stale


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m schemas.export",
        description="Write the JSON Schemas of fedlab's messages and config files.",
        epilog="Example: python -m schemas.export --check",
    )
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_DIR, metavar="DIR", help="where to write the files"
    )
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if the files are stale"
    )
    args = parser.parse_args(argv)
    if args.check:
        stale = check(args.out)
        if stale:
            print(
                f"stale JSON Schemas in {args.out}: {', '.join(stale)}; "
                "run: python -m schemas.export",
                file=sys.stderr,
            )
            return 1
        return 0
    for path in export(args.out):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
