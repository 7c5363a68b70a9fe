"""The testbed's network written down (federation/testbed/topology.py): documentation
addresses only, firewall rules, the commands' order; no namespace is made here."""

from __future__ import annotations

import ipaddress
import re

import pytest

from federation.testbed.topology import (
    ADDR,
    LABS,
    LAN_SWITCH,
    MAX_ROME_HOSTS,
    build_commands,
    gateway_ruleset,
    lab_ruleset,
    parse_port,
    parse_sysctl_conf,
    roles,
)

DOC_NETS = [ipaddress.ip_network(n) for n in ("192.0.2.0/24", "198.51.100.0/24", "203.0.113.0/24")]
NS = {lab: f"t-{lab}" for lab in LABS}
NS3 = {role: f"t-{role}" for role in roles(3)}


def _addresses(text: str) -> set[str]:
    return set(re.findall(r"\b\d{1,3}\.\d{1,3}\.\d{1,3}\.\d{1,3}\b", text))


def test_every_address_is_a_documentation_address() -> None:
    text = " ".join(" ".join(c) for c in build_commands(NS, {})) + gateway_ruleset()
    text += " ".join(" ".join(c) for c in build_commands(NS3, {}, 3))
    text += " ".join(ADDR.rome_host(f"rome{i}") for i in range(2, MAX_ROME_HOSTS + 1))
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
    cmds = build_commands(NS3, {"net.ipv4.tcp_mtu_probing": "2"}, 3)
    hosts = {c[3] for c in cmds if "net.ipv4.tcp_mtu_probing=2" in c}
    assert hosts == {NS3[r] for r in ("rome", "rome2", "rome3", "kiruna")}


# -- several hosts on Rome's lab network ------------------------------------------------
def test_one_rome_host_is_the_default_and_has_no_switch() -> None:
    assert roles() == roles(1) == LABS
    flat = [" ".join(c) for c in build_commands(NS, {})]
    assert not any("bridge" in c or "master" in c for c in flat)
    assert "ip -n t-rome link add eth0 type veth peer name lan0 netns t-rome-gw" in flat


def test_more_rome_hosts_add_their_namespaces_and_a_switch() -> None:
    assert roles(3) == (*LABS, "rome2", "rome3", LAN_SWITCH)
    cmds = build_commands(NS3, {}, 3)
    made = [c[3] for c in cmds[: len(NS3)]]
    assert [c[:3] for c in cmds[: len(NS3)]] == [["ip", "netns", "add"]] * len(NS3)
    assert sorted(made) == sorted(NS3.values())  # every namespace made first, once
    assert not any(c[:3] == ["ip", "netns", "add"] for c in cmds[len(NS3) :])


@pytest.mark.parametrize("n", [0, -1, MAX_ROME_HOSTS + 1])
def test_a_bad_number_of_rome_hosts_says_the_range(n: int) -> None:
    with pytest.raises(ValueError, match=f"1 to {MAX_ROME_HOSTS}"):
        roles(n)


def test_rome_hosts_and_the_gateway_share_one_bridge_with_no_address() -> None:
    flat = [" ".join(c) for c in build_commands(NS3, {}, 3)]
    sw = NS3[LAN_SWITCH]
    assert f"ip -n {sw} link add br0 type bridge" in flat
    for name, dev, port in (("rome-gw", "lan0", "gw"), ("rome", "eth0", "h1"),
                            ("rome2", "eth0", "h2"), ("rome3", "eth0", "h3")):  # fmt: skip
        assert f"ip -n {NS3[name]} link add {dev} type veth peer name {port} netns {sw}" in flat
        enslaved = flat.index(f"ip -n {sw} link set {port} master br0")
        assert flat.index(f"ip -n {sw} link set {port} up") > enslaved
    assert not any(c.startswith(f"ip -n {sw} addr") for c in flat)  # a switch, not a router
    # No direct wire between a Rome host and the gateway any more: only through the switch.
    assert not any("peer name lan0" in c for c in flat)


def test_each_rome_host_has_its_address_and_the_gateway_as_default_route() -> None:
    flat = [" ".join(c) for c in build_commands(NS3, {}, 3)]
    for role, address in (("rome", "192.0.2.10"), ("rome2", "192.0.2.11"),
                          ("rome3", "192.0.2.12")):  # fmt: skip
        assert ADDR.rome_host(role) == address
        assert f"ip -n {NS3[role]} addr add {address}/24 dev eth0" in flat
        assert f"ip -n {NS3[role]} route add default via {ADDR.rome_gw_lan}" in flat
    # The gateway's side keeps its name, so its firewall rules (iifname "lan0") apply.
    assert f"ip -n {NS3['rome-gw']} addr add {ADDR.rome_gw_lan}/24 dev lan0" in flat
    assert 'iifname "lan0"' in gateway_ruleset()


@pytest.mark.parametrize(
    "bad", ["rome1", "rome-gw", "kiruna", "rome0", f"rome{MAX_ROME_HOSTS + 1}"]
)
def test_an_unknown_rome_host_says_which_names_exist(bad: str) -> None:
    with pytest.raises(ValueError, match="rome2"):
        ADDR.rome_host(bad)


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
