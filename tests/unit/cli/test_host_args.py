"""``fedlab host``: what one process may host, refused at load naming the file and
field (federation/runtime/host.py, federation/cli/host.py). No session is opened:
every refusal comes before it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from federation import cli
from federation.runtime.host import check_hosted, shared_clocks
from schemas.config import AgentConfig, ConfigError

ENDPOINT = "tcp/127.0.0.1:9"  # never dialled: each case fails before the session


def agent_file(folder: Path, stem: str, **fields: object) -> Path:
    lines = [f'lab = "rome"\nname = "{stem}"\n']
    for key, value in {"role": "member", **fields}.items():
        lines.append(f"{key} = {json.dumps(value)}\n")
    path = folder / f"{stem}.toml"
    path.write_text("".join(lines))
    return path


def test_one_name_twice_is_refused_naming_both_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first = agent_file(tmp_path, "a1")
    (tmp_path / "copy").mkdir()
    second = agent_file(tmp_path / "copy", "a1")
    assert cli.main(["host", str(first), str(second), "-e", ENDPOINT]) == 2
    err = capsys.readouterr().err
    assert f"{second}: lab/name rome/a1 is also {first}'s" in err


def test_a_real_platform_is_refused_naming_file_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    virtual = agent_file(tmp_path, "a1")
    real = agent_file(tmp_path, "a2", platform="serial:/dev/ttyUSB0", wait_start=True)
    assert cli.main(["host", str(virtual), str(real), "-e", ENDPOINT]) == 2
    err = capsys.readouterr().err
    assert f"{real}: platform: serial:/dev/ttyUSB0 is a real platform" in err
    assert "own `fedlab agent`" in err


def test_two_federations_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    one = agent_file(tmp_path, "a1")
    other = agent_file(tmp_path, "a2", federation="other")
    assert cli.main(["host", str(one), str(other), "-e", ENDPOINT]) == 2
    err = capsys.readouterr().err
    assert f"{other}: federation: 'other', but {one}'s is 'default'" in err


def test_a_bad_file_names_file_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = agent_file(tmp_path, "a1")
    bad = agent_file(tmp_path, "a2", pose_rate=-1)
    assert cli.main(["host", str(good), str(bad), "-e", ENDPOINT]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "pose_rate" in err


def test_one_identity_for_several_agents_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    files = [str(agent_file(tmp_path, f"a{i}")) for i in (1, 2)]
    user = 'transport/auth/usrpwd/user:"rome/a1"'
    assert cli.main(["host", *files, "-e", ENDPOINT, "--cfg", user]) == 2
    err = capsys.readouterr().err
    assert "the user name is 'rome/a1'" in err and "2 agents on this one session" in err
    # One agent: identity = name, as for fedlab agent.
    assert cli.main(["host", files[1], "-e", ENDPOINT, "--cfg", user]) == 2
    assert "but this agent is rome/a2" in capsys.readouterr().err


@pytest.mark.parametrize("group", ["0", "-2", "x"])
def test_group_is_a_positive_count(group: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["host", "a.toml", "--group", group])
    assert exit_.value.code == 2
    assert "--group" in capsys.readouterr().err


def test_flags_and_experiment_reach_each_agent(tmp_path: Path) -> None:
    from federation.cli.host import hosted_configs

    experiment = tmp_path / "exp.toml"
    experiment.write_text(
        'name = "pair"\nfederation = "trial"\nduration = 30\n'
        '[[participants]]\nagent = "rome/a1"\nrole = "leader"\n'
        '[[participants]]\nagent = "rome/a2"\nrole = "follower"\nfollow = "rome/a1"\n'
    )
    own = tmp_path / "own.jsonl"
    files = [agent_file(tmp_path, "a1", status_json=str(own)), agent_file(tmp_path, "a2")]
    argv = ["host", *map(str, files), "--experiment", str(experiment)]
    argv += ["--duration", "7", "--status-dir", str(tmp_path / "st")]
    args = cli.build_parser(("host",)).parse_args(argv)
    hosted = dict(hosted_configs(args))
    a1, a2 = hosted[str(files[0])], hosted[str(files[1])]
    assert (a1.role, a2.role, a2.follow) == ("leader", "follower", "rome/a1")
    assert a1.federation == a2.federation == "trial"
    assert a1.duration == a2.duration == 7 and a1.wait_start and a2.wait_start
    assert a1.status_json == own  # the file's own choice is kept
    assert a2.status_json == tmp_path / "st" / "rome-a2.jsonl"


def test_a_file_not_in_the_experiment_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    experiment = tmp_path / "exp.toml"
    experiment.write_text(
        'name = "one"\nduration = 30\n[[participants]]\nagent = "rome/a1"\nrole = "leader"\n'
    )
    stray = agent_file(tmp_path, "zz")
    code = cli.main(["host", str(stray), "--experiment", str(experiment), "-e", ENDPOINT])
    assert code == 2
    assert "rome/zz does not take part (participants: rome/a1)" in capsys.readouterr().err


def test_an_empty_host_is_refused() -> None:
    with pytest.raises(ConfigError, match="no agent to host"):
        check_hosted([])


def test_agents_share_a_clock_only_with_the_same_settings() -> None:
    def config(name: str, **fields: object) -> AgentConfig:
        return AgentConfig.model_validate({"lab": "rome", "name": name, "role": "member", **fields})

    configs = [
        config("a"),
        config("b"),
        config("c", clock_offset=3.0),
        config("d", clock_offset=3.0),
        config("e", clock_drift_ppm=50.0),
        config("f", clock_step=(5.0, 0.5)),
        config("g", clock_step=(5.0, 0.5)),
    ]
    a, b, c, d, e, f, g = shared_clocks(configs)
    assert a is b and c is d
    assert len({id(x) for x in (a, c, e, f, g)}) == 5  # a step moves one agent's clock only
    assert c.offset == 3.0 and e.rate == pytest.approx(1 + 50e-6)


def test_a_folder_stands_for_its_agent_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from federation.cli.host import hosted_configs

    folder = tmp_path / "sim"
    folder.mkdir()
    for stem in ("b", "a"):
        agent_file(folder, stem)
    (folder / "notes.txt").write_text("not an agent")
    args = cli.build_parser(("host",)).parse_args(["host", str(folder)])
    assert [config.name for _, config in hosted_configs(args)] == ["a", "b"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main(["host", str(empty), "-e", ENDPOINT]) == 2
    assert f"{empty}: a folder without agent files" in capsys.readouterr().err


@pytest.mark.parametrize("field", ["status_json", "record"])
def test_two_agents_writing_one_file_are_refused(
    tmp_path: Path, field: str, capsys: pytest.CaptureFixture[str]
) -> None:
    shared = tmp_path / "shared.out"
    one = agent_file(tmp_path, "a1", **{field: str(shared)})
    two = agent_file(tmp_path, "a2", **{field: str(shared)})
    assert cli.main(["host", str(one), str(two), "-e", ENDPOINT]) == 2
    err = capsys.readouterr().err
    assert f"{two}: {field}: {shared} is also {one} ({field})'s" in err


def test_fedlab_agent_takes_its_part_by_the_files_lab_and_name(tmp_path: Path) -> None:
    """``fedlab agent --agent-config FILE --experiment EXP``: the file's lab and name pick
    the part (as for ``fedlab host``); the flags, when given, still win."""
    from federation.cli.agent import agent_config

    experiment = tmp_path / "exp.toml"
    experiment.write_text(
        'name = "pair"\nduration = 30\n'
        '[[participants]]\nagent = "rome/a1"\nrole = "leader"\n'
        '[[participants]]\nagent = "rome/a2"\nrole = "follower"\nfollow = "rome/a1"\n'
    )
    file = agent_file(tmp_path, "a2")
    parser = cli.build_parser(("agent",))
    argv = ["agent", "--agent-config", str(file), "--experiment", str(experiment)]
    config = agent_config(parser.parse_args(argv))
    assert (str(config.agent), config.role, config.follow) == ("rome/a2", "follower", "rome/a1")
    assert agent_config(parser.parse_args([*argv, "--name", "a1"])).role == "leader"


def test_every_participant_keeps_the_leaders_clock_a_follower_of_a_follower_too(
    tmp_path: Path,
) -> None:
    """ctl start's ``at`` is on the leader's clock: an agent that follows a follower
    must not take that follower's clock for reference time (its own default)."""
    from federation.cli.agent import build_agent_config

    experiment = tmp_path / "chain.toml"
    experiment.write_text(
        'name = "chain"\nduration = 30\n'
        '[[participants]]\nagent = "rome/l"\nrole = "leader"\n'
        '[[participants]]\nagent = "kiruna/a"\nrole = "follower"\nfollow = "rome/l"\n'
        '[[participants]]\nagent = "paris/b"\nrole = "follower"\nfollow = "kiruna/a"\n'
    )
    for lab, name in (("rome", "l"), ("kiruna", "a"), ("paris", "b")):
        config = build_agent_config(None, experiment, {"lab": lab, "name": name})
        assert config.reference == "rome/l", (lab, name)
    b = build_agent_config(None, experiment, {"lab": "paris", "name": "b"})
    assert b.follow == "kiruna/a"


@pytest.mark.parametrize(
    ("flags", "said"),
    [
        (["-m", "peer"], "tcp/[::]:0"),  # a peer's default: every interface
        (["-m", "router", "-l", "tcp/0.0.0.0:7447"], "tcp/0.0.0.0:7447"),
    ],
)
def test_an_agent_others_could_reach_without_its_router_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], said: str
) -> None:
    """A peer or router session listening beyond this host: anyone reaching the port
    could publish control or the followed pose into the agent, past the router's ACL."""
    agent = agent_file(tmp_path, "a1")
    assert cli.main(["host", str(agent), "-e", ENDPOINT, *flags]) == 2
    assert said in capsys.readouterr().err
    agent_flags = ["agent", "--role", "leader", "--lab", "rome", "--name", "a", "-e", ENDPOINT]
    assert cli.main([*agent_flags, *flags]) == 2
    assert said in capsys.readouterr().err


def test_a_config_file_without_a_mode_is_a_client(tmp_path: Path) -> None:
    """Zenoh's own default is peer: such a file had made the agent listen everywhere."""
    from federation.runtime.session import build_config, config_value
    from schemas.config import ZenohOptions

    path = tmp_path / "agent.json5"
    path.write_text('{connect: {endpoints: ["tcp/127.0.0.1:7447"]}}\n')
    conf = build_config(ZenohOptions(config=path), default_mode="client")
    assert config_value(conf, "mode") == "client"


def test_an_experiment_leaves_a_hosts_real_platform_and_runs_dir_alone(tmp_path: Path) -> None:
    """The experiment had replaced the file's serial port by its simulated platform (the
    real table idle while a simulated one flew the run) and its runs_dir by ``runs``."""
    from federation.cli.agent import build_agent_config
    from schemas.config import ConfigError

    experiment = (
        Path(__file__).resolve().parents[3] / "deploy" / "experiments" / "attitude-tracking.toml"
    )
    real = tmp_path / "knatte.toml"
    real.write_text(
        'lab = "kiruna"\nname = "knatte"\nrole = "leader"\nplatform = "serial:/dev/ttyUSB0"\n'
        'runs_dir = "/data/fedlab-runs"\nwait_start = true\n'
    )
    config = build_agent_config(real, experiment, {})
    assert config.platform == "serial:/dev/ttyUSB0" and config.platform_preset == "knatte"
    assert str(config.runs_dir) == "/data/fedlab-runs"
    assert config.role == "leader" and config.wait_start  # the experiment's part
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(real.read_text() + 'platform_preset = "pinocchio"\n')
    with pytest.raises(ConfigError, match=r"platform_preset.*'pinocchio'.*'knatte'"):
        build_agent_config(wrong, experiment, {})
