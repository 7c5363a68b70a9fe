"""``fedlab bench table``: the README's benchmark table is the one generated from the
committed result files, and benchmarks/ holds exactly the files it reads (plus their
inputs), each named with its command in benchmarks/README.md."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation import cli
from federation.bench import table

ROOT = Path(__file__).resolve().parents[3]
BENCHMARKS = ROOT / "benchmarks"
START, END = "<!-- bench-table: fedlab bench table -->", "<!-- /bench-table -->"


def test_the_readme_table_is_the_generated_one() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert START in readme and END in readme, f"README.md has no {START} ... {END} block"
    committed = readme.split(START, 1)[1].split(END, 1)[0].strip("\n") + "\n"
    assert committed == table.table_markdown(BENCHMARKS), (
        "README.md's benchmark table differs from the result files: "
        "run `fedlab bench table` and paste its output between the markers"
    )


def test_every_result_file_is_read_and_listed_with_its_command() -> None:
    on_disk = {p.name for p in BENCHMARKS.glob("*.json")}
    read = set(table.FILES)
    # Read by other tests and by `fedlab bench sync --replay`, not by the table.
    others = {"sync-testbed-replay.json", "network-tcp-tuned-60s.json"}
    others |= {"network-multilink-qos-60s.json"}
    # docs/deploy.md's "Pose under loss on the secure path" (TLS and QUIC lab links).
    others |= {"network-secure-loss5-60s.json", "network-quic-loss5-seeds45-60s.json"}
    others |= {"network-quic-references-loss5-60s.json", "network-quic-cut-loss20-60s.json"}
    others |= {"network-quic-clean-loss1-60s.json"}
    assert on_disk == read | others
    listing = (BENCHMARKS / "README.md").read_text(encoding="utf-8")
    missing = [name for name in on_disk if f"`{name}`" not in listing]
    assert not missing, f"benchmarks/README.md does not name {missing}"
    assert {row[4] for row in table.rows(BENCHMARKS)} == read


def test_the_command_prints_the_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["bench", "table", "--dir", str(BENCHMARKS)]) == 0
    assert capsys.readouterr().out == table.table_markdown(BENCHMARKS)


def test_a_missing_folder_is_an_error_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["bench", "table", "--dir", str(tmp_path / "none")]) == 1
    assert "none" in capsys.readouterr().err
