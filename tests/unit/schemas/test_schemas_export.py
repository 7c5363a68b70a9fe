"""The committed JSON Schemas (schemas/json/) match the models, and the protocol names them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from schemas import export

ROOT = Path(__file__).resolve().parents[3]
PROTOCOL = ROOT / "docs" / "protocol.md"


@pytest.mark.parametrize("model", export.MODELS, ids=lambda m: m.__name__)
def test_committed_schema_equals_a_fresh_export(model: type) -> None:
    path = export.DEFAULT_DIR / export.file_name(model)
    assert path.exists(), f"{path} missing: run python -m schemas.export"
    assert path.read_text(encoding="utf-8") == export.render(model), (
        f"{path.name} drifted from {model.__module__}.{model.__name__}: "
        "run python -m schemas.export and commit schemas/json/"
    )


def test_no_stray_schema_files() -> None:
    expected = {export.file_name(m) for m in export.MODELS}
    assert {p.name for p in export.DEFAULT_DIR.glob("*.schema.json")} == expected


def test_schema_files_are_json_schema_2020_12() -> None:
    for model in export.MODELS:
        schema = json.loads((export.DEFAULT_DIR / export.file_name(model)).read_text())
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        assert schema["title"] == model.__name__
        assert schema["type"] == "object"


def test_protocol_names_every_message_schema_file() -> None:
    text = PROTOCOL.read_text(encoding="utf-8")
    missing = [f for f in map(export.file_name, export.MESSAGES) if f not in text]
    assert not missing, f"docs/protocol.md does not mention {missing}"


def test_module_check_mode_and_export_to_another_dir(tmp_path: Path) -> None:
    run = [sys.executable, "-m", "schemas.export"]
    fresh = subprocess.run([*run, "--out", str(tmp_path)], capture_output=True, text=True)
    assert fresh.returncode == 0, fresh.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        export.file_name(m) for m in export.MODELS
    )
    ok = subprocess.run([*run, "--check", "--out", str(tmp_path)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    (tmp_path / "Status.schema.json").write_text("{}\n")
    stale = subprocess.run(
        [*run, "--check", "--out", str(tmp_path)], capture_output=True, text=True
    )
    assert stale.returncode == 1
    assert "Status.schema.json" in stale.stderr
