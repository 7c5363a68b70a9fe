"""Export the JSON Schemas of fedlab's messages and configuration files.

Writes ``schemas/json/<Name>.schema.json`` (JSON Schema draft 2020-12, from pydantic's
``model_json_schema()``) for every model in :data:`MODELS`, so a client written in
another language can validate what it publishes and reads without Python::

    python -m schemas.export            # (re)write schemas/json/
    python -m schemas.export --check    # exit 1 if the files on disk differ from the models
    fedlab schemas [--check]            # the same, from the fedlab command

The files are committed; ``tests/unit/schemas/test_schemas_export.py`` fails when a
model changes and the files were not regenerated.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from schemas.config import AgentConfig, RouterConfig
from schemas.experiment import ExperimentConfig
from schemas.federation import FederationFile
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
    FederationFile,
)
"""What operators write: agent, router, experiment, platform and federation files."""

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


_USAGE = "usage: python -m schemas.export [--check] [--out DIR]  (or: fedlab schemas)"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m schemas.export [--check] [--out DIR]``: write the files, or with
    ``--check`` write nothing and return 1 if they are stale.

    Its two flags are read by hand: argparse lives in :mod:`federation.cli`, which
    schemas may not import (``fedlab schemas`` is the same with full help).
    """
    out, check_only = DEFAULT_DIR, False
    args = iter(sys.argv[1:] if argv is None else argv)
    for arg in args:
        if arg == "--check":
            check_only = True
        elif arg == "--out" or arg.startswith("--out="):
            value = arg.partition("=")[2] or next(args, "")
            if not value:
                print(f"{_USAGE}\nerror: --out needs a directory", file=sys.stderr)
                return 2
            out = Path(value)
        elif arg in ("-h", "--help"):
            print(f"{_USAGE}\n\n{(__doc__ or '').strip()}")
            return 0
        else:
            print(f"{_USAGE}\nerror: unexpected argument {arg!r}", file=sys.stderr)
            return 2
    if check_only:
        stale = check(out)
        if stale:
            print(
                f"stale JSON Schemas in {out}: {', '.join(stale)}; run: python -m schemas.export",
                file=sys.stderr,
            )
            return 1
        return 0
    for path in export(out):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
