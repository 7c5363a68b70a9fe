"""Every command's help shows each option's default once, and on/off flags read the
right way round (``--no-icmp`` never says ``(default: True)``)."""

from __future__ import annotations

import argparse
import re
from collections.abc import Iterator

import pytest

from federation.cli import build_parser
from federation.cli.common import Formatter


def parsers(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from parsers(child, (*path, name))


def option_helps(parser: argparse.ArgumentParser) -> Iterator[tuple[argparse.Action, str]]:
    """Each option's help as the formatter renders it, unwrapped."""
    formatter = parser._get_formatter()
    for action in parser._actions:
        if action.help not in (None, argparse.SUPPRESS):
            yield action, formatter._expand_help(action)


ALL = [pytest.param(path, p, id=" ".join(path) or "fedlab") for path, p in parsers(build_parser())]


@pytest.mark.parametrize(("path", "parser"), ALL)
def test_each_default_is_shown_once_and_never_as_none_or_a_flags_state(
    path: tuple[str, ...], parser: argparse.ArgumentParser
) -> None:
    text = parser.format_help()
    flat = " ".join(text.split())
    assert "(default: None)" not in flat, path
    assert "(default: [])" not in flat, path
    for action, help_text in option_helps(parser):
        where = (path, action.option_strings)
        assert len(re.findall(r"\(default", help_text)) <= 1, (where, help_text)
        if action.nargs == 0:  # an on/off flag: its name says what giving it does
            assert "(default: True)" not in help_text, (where, help_text)
            assert "(default: False)" not in help_text, (where, help_text)


@pytest.mark.parametrize(("path", "parser"), ALL)
def test_an_option_with_a_default_says_what_it_is(
    path: tuple[str, ...], parser: argparse.ArgumentParser
) -> None:
    for action, help_text in option_helps(parser):
        value = action.default
        if action.nargs == 0 or value in (None, argparse.SUPPRESS, []):
            continue
        assert "default" in help_text.lower(), (path, action.option_strings, help_text)


def _rendered(*options: tuple[list[str], dict[str, object]]) -> str:
    parser = argparse.ArgumentParser(prog="x", formatter_class=Formatter)
    for flags, kwargs in options:
        parser.add_argument(*flags, **kwargs)  # type: ignore[arg-type]
    return " ".join(parser.format_help().split())


def test_the_formatter_appends_a_default_once_and_none_for_flags() -> None:
    text = _rendered(
        (["--rate"], {"type": float, "default": 2.0, "help": "per second"}),
        (["--said"], {"default": "a", "help": "what (default: a, or b)"}),
        (["--unset"], {"help": "nothing given"}),
        (["--many"], {"action": "append", "default": [], "help": "repeatable"}),
        (["--no-icmp"], {"dest": "icmp", "action": "store_false", "help": "drop silently"}),
        (["--fast"], {"action": "store_true", "help": "go fast"}),
    )
    assert "per second (default: 2.0)" in text
    assert "what (default: a, or b) --unset" in text
    assert "nothing given --many" in text
    assert "repeatable --no-icmp" in text
    assert "drop silently --fast" in text
    assert text.endswith("go fast")


@pytest.mark.parametrize(("path", "parser"), ALL)
def test_no_example_writes_into_the_packages_own_folder(
    path: tuple[str, ...], parser: argparse.ArgumentParser
) -> None:
    # federation/ is fedlab's own package in a clone: generated files go elsewhere (fed/).
    assert "--out federation" not in parser.format_help(), path
