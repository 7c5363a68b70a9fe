"""The generated reference pages (docs/reference/) are what the parsers and the models
say today: every command, every option, every configuration field."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from federation import cli
from federation.cli import reference
from schemas import export

ROOT = Path(__file__).resolve().parents[3]
DOCS = ROOT / "docs" / "reference"


@pytest.mark.parametrize("name", sorted(reference.PAGES))
def test_the_committed_page_is_the_generated_one(name: str) -> None:
    path = DOCS / name
    assert path.exists(), f"{path} missing: run fedlab schemas --docs"
    assert path.read_text(encoding="utf-8") == reference.PAGES[name](), (
        f"docs/reference/{name} differs from the code: run `fedlab schemas --docs` "
        "and commit docs/reference/"
    )


def _parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                found += _parsers(child)
    return found


def test_every_command_and_option_is_on_the_page() -> None:
    page = reference.commands_markdown()
    for parser in _parsers(cli.build_parser()):
        assert f"`{parser.prog}`" in page, parser.prog
        for action in parser._actions:
            for flag in action.option_strings:
                if flag not in ("-h", "--help"):
                    assert flag in page, f"{parser.prog} {flag}"


def test_every_config_field_is_on_the_page() -> None:
    page = reference.config_markdown()
    for model in export.CONFIGS:
        assert f"## {model.__name__}" in page
        for name, field in model.model_fields.items():
            assert f"| `{field.alias or name}` |" in page, f"{model.__name__}.{name}"


def test_the_page_is_the_same_on_any_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "40")
    narrow = reference.commands_markdown()
    monkeypatch.setenv("COLUMNS", "250")
    assert reference.commands_markdown() == narrow
    assert str(ROOT) not in narrow


def test_docs_writes_and_check_says_stale(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["schemas", "--docs", "--docs-dir", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(reference.PAGES)
    assert cli.main(["schemas", "--docs", "--check", "--docs-dir", str(tmp_path)]) == 0
    (tmp_path / "config.md").write_text("# old\n")
    capsys.readouterr()
    assert cli.main(["schemas", "--docs", "--check", "--docs-dir", str(tmp_path)]) == 1
    assert "config.md" in capsys.readouterr().err
