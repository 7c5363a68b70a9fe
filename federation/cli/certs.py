"""``fedlab certs init|issue|issue-agent``: a federation's CA and its labs' and agents'
certificates (:mod:`federation.deploy.certs`). They open no Zenoh session: no Zenoh flags.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from federation.cli.common import Formatter, Subparsers
from federation.core import keys
from federation.deploy import certs

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "certs",
        help="create the federation CA and the labs' and agents' certificates",
        formatter_class=Formatter,
        description=(
            "A federation's certificate authority signs one certificate per lab router (mutual\n"
            "TLS between labs) and one per agent (its identity for the lab router's access\n"
            "control). Keys are written with mode 0600. See docs/deploy.md."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab certs init --dir /etc/fedlab/certs --federation default\n"
            "  fedlab certs issue kiruna --dir /etc/fedlab/certs --host kiruna.example.org\n"
            "  fedlab certs issue-agent kiruna knatte --dir /etc/fedlab/certs"
        ),
    )
    actions = p.add_subparsers(dest="certs_command", required=True, metavar="ACTION")

    def common(q: argparse.ArgumentParser, days: int) -> None:
        q.add_argument(
            "--dir", type=Path, default=certs.DEFAULT_DIR, metavar="DIR", help="certificate folder"
        )
        q.add_argument("--force", action="store_true", help="replace existing files")
        q.add_argument("--days", type=int, default=days, metavar="N", help="days of validity")

    q = actions.add_parser(
        "init",
        help="create the federation CA (ca.pem, ca.key)",
        formatter_class=Formatter,
        description="Create the federation CA. Refuses to replace an existing one without --force.",
        epilog="Example: fedlab certs init --dir /etc/fedlab/certs --federation default",
    )
    q.add_argument(
        "--federation", default=keys.DEFAULT_FEDERATION, metavar="NAME", help="federation name"
    )
    common(q, certs.CA_DAYS)
    q.set_defaults(func=run, issue=_init)

    q = actions.add_parser(
        "issue",
        help="issue a lab router's certificate (<lab>.pem, <lab>.key)",
        formatter_class=Formatter,
        description=(
            "Issue a lab router's certificate, signed by the CA in --dir. CN is the lab name;\n"
            "every --host (DNS name or IP address) becomes a Subject Alternative Name: give\n"
            "each name other labs' routers and this lab's agents dial."
        ),
        epilog=(
            "Example:\n"
            "  fedlab certs issue kiruna --dir /etc/fedlab/certs --host kiruna.example.org"
        ),
    )
    q.add_argument("lab", help="lab name")
    q.add_argument(
        "--host",
        action="append",
        default=argparse.SUPPRESS,
        metavar="NAME",
        help=f"host name or address (repeatable; default: {', '.join(certs.DEFAULT_HOSTS)})",
    )
    common(q, certs.LEAF_DAYS)
    q.set_defaults(func=run, issue=_lab)

    q = actions.add_parser(
        "issue-agent",
        help="issue an agent's client certificate (<lab>.<name>.pem, .key)",
        formatter_class=Formatter,
        description=(
            "Issue an agent's client certificate, signed by the CA in --dir. Its CN is\n"
            "'<lab>/<name>': list it in the lab router's access_control subjects (fedlab\n"
            "deploy generate issues every certificate and writes the ACL from one file)."
        ),
        epilog="Example: fedlab certs issue-agent kiruna knatte --dir /etc/fedlab/certs",
    )
    q.add_argument("lab", help="the agent's lab")
    q.add_argument("name", help="the agent's name")
    common(q, certs.LEAF_DAYS)
    q.set_defaults(func=run, issue=_agent)


def _init(args: argparse.Namespace) -> certs.Issued:
    return certs.init_ca(args.dir, args.federation, force=args.force, days=args.days)


def _lab(args: argparse.Namespace) -> certs.Issued:
    hosts = getattr(args, "host", None) or certs.DEFAULT_HOSTS
    return certs.issue_lab(args.dir, args.lab, hosts, force=args.force, days=args.days)


def _agent(args: argparse.Namespace) -> certs.Issued:
    return certs.issue_agent(args.dir, args.lab, args.name, force=args.force, days=args.days)


def run(args: argparse.Namespace) -> int:
    issue: Callable[[argparse.Namespace], certs.Issued] = args.issue
    try:
        issued = issue(args)
    except (ValueError, OSError) as error:  # CertError is a ValueError
        print(f"fedlab certs: error: {error}", file=sys.stderr)
        return 2
    print(f"CN {issued.common_name!r}: certificate {issued.cert}, key {issued.key} (mode 0600)")
    return 0
