"""The testbed's network: which namespaces, links, addresses, routes and firewall
rules make two labs and the internet between them. Pure: this module only writes
the commands and rulesets down (:func:`build_commands`, :func:`gateway_ruleset`,
:func:`lab_ruleset`); :mod:`federation.testbed.bed` runs them.

::

    rome                rome-gw                wan                    kiruna
    eth0 192.0.2.10 --- lan0 192.0.2.1
                        wan0 198.51.100.2 ---- rome0 198.51.100.1
                                               imp0 (TUN: the stage)
                                               kir0 203.0.113.1 ----- eth0 203.0.113.10

- **rome-gw** masquerades Rome's lab network behind 198.51.100.2 and keeps a
  stateful firewall: what Rome's hosts open goes out and its replies come back;
  nothing unsolicited gets in, to the gateway or past it.
- **kiruna** accepts only the ports it lists (``tcp/7447`` by default) and
  replies to what it opened.
- **wan** forwards between the two sides through a TUN device (policy routing:
  whatever arrives on ``rome0`` or ``kir0`` goes into ``imp0``), where the packet
  stage (:mod:`federation.link.tun`) delays, drops or cuts it and writes it back
  for the kernel to forward on. It also routes 192.0.2.0/24 to Rome's gateway, so
  a direct connection into Rome's lab does reach the gateway and meets its firewall.

With ``rome_hosts`` N > 1 (:func:`roles`), Rome's lab has N hosts on one LAN: a
switch namespace **rome-lan** holds a bridge (``br0``, no address, no firewall)
whose ports are wired to the gateway's ``lan0`` and to ``eth0`` of ``rome``
(192.0.2.10), ``rome2`` (192.0.2.11), ... ``romeN``, all behind the same gateway::

    rome   eth0 192.0.2.10 --- h1 --+      rome-lan               rome-gw
    rome2  eth0 192.0.2.11 --- h2 --+-- br0 ----------- gw --- lan0 192.0.2.1
    ...                             |

A switch of its own rather than a bridge in the gateway: the gateway's rules stay
as they are, and traffic between the lab's hosts never meets them (even where the
host kernel has ``br_netfilter`` loaded). With N = 1 (the default) the
network is exactly the one drawn first.

Only documentation addresses (RFC 5737) are used.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

__all__ = [
    "LABS",
    "LAN_SWITCH",
    "MAX_ROME_HOSTS",
    "ROME_LAN",
    "Addresses",
    "build_commands",
    "gateway_ruleset",
    "lab_ruleset",
    "parse_port",
    "parse_sysctl_conf",
    "roles",
    "rome_hosts",
]

LABS = ("rome", "rome-gw", "wan", "kiruna")
"""The namespaces, by role (their real names carry the testbed's prefix)."""

ROME_LAN = "192.0.2.0/24"
LAN_SWITCH = "rome-lan"
"""The switch namespace of Rome's lab network (only with more than one Rome host)."""
MAX_ROME_HOSTS = 40
"""Rome's hosts are 192.0.2.10 onwards: 40 keeps them well inside the /24."""


@dataclass(frozen=True)
class Addresses:
    """Who is where (RFC 5737 documentation ranges only)."""

    rome: str = "192.0.2.10"  # Rome's lab host: router and agents
    rome_gw_lan: str = "192.0.2.1"
    rome_gw_wan: str = "198.51.100.2"  # Rome's one public address (NAT)
    wan_rome: str = "198.51.100.1"
    wan_kiruna: str = "203.0.113.1"
    kiruna: str = "203.0.113.10"  # Kiruna's lab host: public, one port open
    kiruna_net: str = "203.0.113.0/24"  # the stage's forward direction: towards Kiruna

    def rome_host(self, role: str) -> str:
        """The address of a Rome host by role: ``rome`` 192.0.2.10, ``rome2`` .11, ..."""
        index = _rome_index(role)
        return str(ipaddress.ip_address(self.rome) + index - 1)


ADDR = Addresses()
TUN = "imp0"
_TABLE = "100"


def _rome_index(role: str) -> int:
    """``rome`` -> 1, ``rome2`` -> 2, ...; ValueError for anything else."""
    rest = role.removeprefix("rome")
    if rest == "":
        return 1
    if role.startswith("rome") and rest.isdigit() and 2 <= int(rest) <= MAX_ROME_HOSTS:
        return int(rest)
    raise ValueError(f"{role!r} is not a Rome host: expected rome, rome2 ... rome{MAX_ROME_HOSTS}")


def rome_hosts(n: int) -> tuple[str, ...]:
    """The roles of Rome's ``n`` lab hosts: ``rome``, ``rome2``, ... ``romeN``."""
    if not 1 <= n <= MAX_ROME_HOSTS:
        raise ValueError(f"rome_hosts={n}: expected 1 to {MAX_ROME_HOSTS}")
    return ("rome", *(f"rome{i}" for i in range(2, n + 1)))


def roles(n_rome_hosts: int = 1) -> tuple[str, ...]:
    """Every namespace's role: :data:`LABS`, then with more than one Rome host the
    others (``rome2`` ...) and Rome's lab switch (:data:`LAN_SWITCH`)."""
    hosts = rome_hosts(n_rome_hosts)
    return LABS if len(hosts) == 1 else (*LABS, *hosts[1:], LAN_SWITCH)


def parse_port(text: str) -> tuple[str, int]:
    """``tcp/7447`` or ``udp/7447`` -> (protocol, port); ValueError saying why."""
    proto, sep, port = text.partition("/")
    if not sep or proto not in ("tcp", "udp") or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"port {text!r}: expected tcp/PORT or udp/PORT, e.g. tcp/7447")
    return proto, int(port)


def parse_sysctl_conf(text: str) -> dict[str, str]:
    """``key = value`` lines of a sysctl.d file (comments and blanks skipped)."""
    out = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        key, sep, value = line.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ValueError(f"line {number}: expected key = value, not {line!r}")
        out[key.strip()] = value.strip()
    return out


def gateway_ruleset() -> str:
    """Rome's gateway: masquerade, and a stateful firewall that lets nothing in."""
    return """\
table inet fedlab_gw {
    chain input {
        type filter hook input priority filter; policy drop;
        iifname "lo" accept
        ct state established,related accept
        iifname "lan0" accept
        counter comment "unsolicited to the gateway"
    }
    chain forward {
        type filter hook forward priority filter; policy drop;
        ct state established,related accept
        iifname "lan0" oifname "wan0" accept
        counter comment "unsolicited into the lab"
    }
}
table ip fedlab_nat {
    chain postrouting {
        type nat hook postrouting priority srcnat; policy accept;
        oifname "wan0" masquerade
    }
}
"""


def lab_ruleset(ports: Iterable[str]) -> str:
    """A public lab host (Kiruna): only ``ports`` (``tcp/7447``, ...) are open."""
    opened = "".join(
        f"        {proto} dport {port} accept\n" for proto, port in map(parse_port, ports)
    )
    return (
        "table inet fedlab_lab {\n"
        "    chain input {\n"
        "        type filter hook input priority filter; policy drop;\n"
        '        iifname "lo" accept\n'
        "        ct state established,related accept\n"
        f"{opened}"
        '        counter comment "closed ports"\n'
        "    }\n"
        "}\n"
    )


def build_commands(
    ns: Mapping[str, str], sysctls: Mapping[str, str], n_rome_hosts: int = 1
) -> list[list[str]]:
    """The ``ip`` and ``sysctl`` commands that build the network, in order, given the
    real namespace name of each role in :func:`roles` (``ns["rome"]``, ...). Each
    command is run as is (the ones inside a namespace start with
    ``ip netns exec NS``); the namespaces are made first. ``sysctls`` are set on every
    lab host (e.g. TCP settings a lab's host would have). ``n_rome_hosts`` > 1 puts
    Rome's hosts and its gateway on one switch (see the module's docstring)."""
    a = ADDR
    hosts = rome_hosts(n_rome_hosts)
    names = [ns[role] for role in roles(n_rome_hosts)]
    gw, wan, kir = ns["rome-gw"], ns["wan"], ns["kiruna"]

    def ip(name: str, *args: str) -> list[str]:
        return ["ip", "-n", name, *args]

    def sysctl(name: str, key: str, value: str) -> list[str]:
        return ["ip", "netns", "exec", name, "sysctl", "-q", "-w", f"{key}={value}"]

    cmds: list[list[str]] = [["ip", "netns", "add", n] for n in names]
    cmds += [ip(n, "link", "set", "lo", "up") for n in names]
    # The wires: created inside one namespace, the peer end moved to the other.
    if len(hosts) == 1:
        cmds.append(
            ip(ns["rome"], "link", "add", "eth0", "type", "veth", "peer", "name", "lan0",
               "netns", gw)
        )  # fmt: skip
    else:  # Rome's LAN: a bridge in the switch namespace, one port per host and the gateway
        sw = ns[LAN_SWITCH]
        cmds += [ip(sw, "link", "add", "br0", "type", "bridge"), ip(sw, "link", "set", "br0", "up")]
        ports = [(gw, "lan0", "gw")]
        ports += [(ns[host], "eth0", f"h{i}") for i, host in enumerate(hosts, 1)]
        for name, dev, port in ports:
            cmds += [
                ip(name, "link", "add", dev, "type", "veth", "peer", "name", port, "netns", sw),
                ip(sw, "link", "set", port, "master", "br0"),
                ip(sw, "link", "set", port, "up"),
            ]
    cmds += [
        ip(gw, "link", "add", "wan0", "type", "veth", "peer", "name", "rome0", "netns", wan),
        ip(kir, "link", "add", "eth0", "type", "veth", "peer", "name", "kir0", "netns", wan),
    ]
    for name, dev, cidr in (
        *((ns[host], "eth0", f"{a.rome_host(host)}/24") for host in hosts),
        (gw, "lan0", f"{a.rome_gw_lan}/24"),
        (gw, "wan0", f"{a.rome_gw_wan}/24"),
        (wan, "rome0", f"{a.wan_rome}/24"),
        (wan, "kir0", f"{a.wan_kiruna}/24"),
        (kir, "eth0", f"{a.kiruna}/24"),
    ):
        cmds += [ip(name, "addr", "add", cidr, "dev", dev), ip(name, "link", "set", dev, "up")]
    cmds += [ip(ns[host], "route", "add", "default", "via", a.rome_gw_lan) for host in hosts]
    cmds += [
        ip(gw, "route", "add", "default", "via", a.wan_rome),
        ip(kir, "route", "add", "default", "via", a.wan_kiruna),
        ip(wan, "route", "add", ROME_LAN, "via", a.rome_gw_wan),
    ]
    # The WAN: everything arriving from either side goes through the TUN device.
    cmds += [
        ip(wan, "tuntap", "add", "dev", TUN, "mode", "tun"),
        ip(wan, "link", "set", TUN, "up"),
        ip(wan, "route", "add", "default", "dev", TUN, "table", _TABLE),
        ip(wan, "rule", "add", "iif", "rome0", "lookup", _TABLE),
        ip(wan, "rule", "add", "iif", "kir0", "lookup", _TABLE),
    ]
    for name in (gw, wan):
        cmds.append(sysctl(name, "net.ipv4.ip_forward", "1"))
    for dev in ("all", "default", TUN, "rome0", "kir0"):
        cmds.append(sysctl(wan, f"net.ipv4.conf.{dev}.rp_filter", "0"))
    for name in (*(ns[host] for host in hosts), kir):
        cmds += [sysctl(name, key, value) for key, value in sysctls.items()]
    return cmds
