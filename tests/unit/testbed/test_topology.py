"""The testbed's network written down (federation/testbed/topology.py): documentation
addresses only, firewall rules, the commands' order; no namespace is made here."""

from __future__ import annotations

import ipaddress
import re

import pytest

from federation.testbed.topology import (
    ADDR,
    LABS,
    build_commands,
    gateway_ruleset,
    lab_ruleset,
    parse_port,
    parse_sysctl_conf,
)

DOC_NETS = [ipaddress.ip_network(n) for n in ("192.0.2.0/24", "198.51.100.0/24", "203.0.113.0/24")]
NS = {lab: f"t-{lab}" for lab in LABS}


def _addresses(text: str) -> set[str]:
    return set(re.findall(r"\b\d{1,3}\.\d{1,3}\.\d{1,3}\.\d{1,3}\b", text))


def test_every_address_is_a_documentation_address() -> None:
    text = " ".join(" ".join(c) for c in build_commands(NS, {})) + gateway_ruleset()
    text += " ".join(str(v) for v in vars(ADDR).values())
    found = _addresses(text)
    assert found
    for address in found:
        assert any(ipaddress.ip_address(address) in net for net in DOC_NETS), address


def test_namespaces_are_made_first_and_the_tun_route_after_the_device() -> None:
    cmds = build_commands(NS, {})
    assert [c[:3] for c in cmds[:4]] == [["ip", "netns", "add"]] * 4
    flat = [" ".join(c) for c in cmds]
    made = next(i for i, c in enumerate(flat) if "tuntap add dev imp0" in c)
    routed = next(i for i, c in enumerate(flat) if "default dev imp0 table" in c)
    assert made < routed
    assert any("rule add iif rome0" in c for c in flat)
    assert any("rule add iif kir0" in c for c in flat)


def test_lab_sysctls_go_to_both_lab_hosts_only() -> None:
    cmds = build_commands(NS, {"net.ipv4.tcp_mtu_probing": "2"})
    hosts = {c[3] for c in cmds if "net.ipv4.tcp_mtu_probing=2" in c}
    assert hosts == {NS["rome"], NS["kiruna"]}


def test_the_gateway_masquerades_and_lets_nothing_unsolicited_in() -> None:
    rules = gateway_ruleset()
    assert 'oifname "wan0" masquerade' in rules
    assert rules.count("policy drop") == 2
    assert "ct state established,related accept" in rules
    assert 'iifname "lan0" oifname "wan0" accept' in rules
    assert 'iifname "wan0" accept' not in rules


def test_a_lab_opens_exactly_its_ports() -> None:
    rules = lab_ruleset(["tcp/7447", "udp/7447"])
    assert "tcp dport 7447 accept" in rules and "udp dport 7447 accept" in rules
    assert "policy drop" in rules
    assert "dport" not in lab_ruleset([])


@pytest.mark.parametrize("bad", ["7447", "sctp/7447", "tcp/0", "tcp/70000", "tcp/x"])
def test_a_bad_port_says_what_is_expected(bad: str) -> None:
    with pytest.raises(ValueError, match="tcp/PORT"):
        parse_port(bad)


def test_the_shipped_sysctl_file_parses() -> None:
    from pathlib import Path

    text = (Path(__file__).parents[3] / "deploy" / "sysctl" / "90-fedlab-wan.conf").read_text()
    settings = parse_sysctl_conf(text)
    assert settings["net.ipv4.tcp_mtu_probing"] == "2"
    assert set(settings) == {
        "net.ipv4.tcp_mtu_probing", "net.ipv4.tcp_base_mss", "net.ipv4.tcp_rto_max_ms",
    }  # fmt: skip


def test_a_bad_sysctl_line_names_its_number() -> None:
    with pytest.raises(ValueError, match="line 2"):
        parse_sysctl_conf("# ok\nnet.ipv4.x\n")
