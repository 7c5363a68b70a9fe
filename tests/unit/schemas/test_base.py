"""schemas.base: a bad config names file, field and reason; an unknown field names the
closest known one."""

from __future__ import annotations

from pathlib import Path

import pytest

from schemas.base import ConfigError, known_fields, load_model
from schemas.config import AgentConfig, ManeuverConfig
from schemas.experiment import load_experiment
from schemas.federation import FederationFile, load_federation

ROOT = Path(__file__).resolve().parents[3]
FEDERATION = ROOT / "deploy" / "federation.example.toml"
FORMATION = ROOT / "deploy" / "experiments" / "formation.toml"


def _agent(tmp_path: Path, text: str) -> str:
    path = tmp_path / "agent.toml"
    path.write_text('lab = "kiruna"\nname = "knatte"\nrole = "leader"\n' + text)
    with pytest.raises(ConfigError) as error:
        load_model(AgentConfig, path)
    return str(error.value)


def test_a_misspelled_field_names_file_field_and_the_closest_known_one(tmp_path: Path) -> None:
    message = _agent(tmp_path, "sync_perod = 0.2\n")
    assert message == (
        f"{tmp_path / 'agent.toml'}: field 'sync_perod': unknown field "
        "(did you mean 'sync_period'?)"
    )


def test_a_misspelled_field_of_a_nested_table_is_matched_against_that_table(
    tmp_path: Path,
) -> None:
    message = _agent(tmp_path, "[maneuver]\namplitud_deg = 3\n")
    assert "field 'maneuver.amplitud_deg': unknown field (did you mean 'amplitude_deg'?)" in message


def test_a_field_like_no_known_one_lists_a_small_tables_fields(tmp_path: Path) -> None:
    message = _agent(tmp_path, "[maneuver]\nzzz = 1\n")
    assert message.endswith(
        "field 'maneuver.zzz': unknown field (known here: amplitude_deg, duration, still)"
    )
    # AgentConfig has too many fields to list: no hint at all.
    assert _agent(tmp_path, "qqqqqqqq = 1\n").endswith("field 'qqqqqqqq': unknown field")


def test_the_known_fields_follow_dicts_lists_and_unions() -> None:
    assert known_fields(AgentConfig, ["maneuver"]) == set(ManeuverConfig.model_fields)
    lab = known_fields(FederationFile, ["labs", "kiruna"])
    assert {"auth", "listen", "agents", "dial"} <= lab
    assert "role" in known_fields(FederationFile, ["labs", "kiruna", "agents", "knatte"])


@pytest.mark.parametrize(
    ("old", "new", "said"),
    [
        (
            'platform = "knatte"',
            'platfrom = "knatte"',
            "labs.kiruna.agents.knatte.platfrom': unknown field (did you mean 'platform'?)",
        ),
        (
            'agent_endpoint = "tls/rome',
            'agent_endpont = "tls/rome',
            "labs.rome.agent_endpont': unknown field (did you mean 'agent_endpoint'?)",
        ),
        (
            'platform = "knatte"',
            'platform = "knatte"\nsettings = { sync_perod = 1 }',
            "labs.kiruna.agents.knatte': agent: field 'sync_perod': unknown field "
            "(did you mean 'sync_period'?)",
        ),
    ],
)
def test_a_federation_files_misspelled_field_gets_a_did_you_mean(
    tmp_path: Path, old: str, new: str, said: str
) -> None:
    text = FEDERATION.read_text()
    assert old in text
    path = tmp_path / "federation.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as error:
        load_federation(path)
    assert f"{path}: field '{said}" in str(error.value)


def test_an_experiments_misspelled_field_in_a_scenario_table_and_a_list(tmp_path: Path) -> None:
    text = FORMATION.read_text()
    path = tmp_path / "formation.toml"
    path.write_text(
        text.replace("radius = 0.4", "radus = 0.4").replace('role = "leader"', 'rol = "leader"', 1)
    )
    with pytest.raises(ConfigError) as error:
        load_experiment(path)
    assert "field 'formation.radus': unknown field (did you mean 'radius'?)" in str(error.value)
    assert "field 'participants.0.rol': unknown field (did you mean 'role'?)" in str(error.value)
