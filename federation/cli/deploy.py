"""``fedlab deploy generate``: every lab's router config, every agent's and operator's
Zenoh config, the certificates and the systemd units, from one federation file
(:mod:`federation.deploy.generate`). It opens no Zenoh session: no Zenoh flags.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from federation.cli.common import Formatter, Subparsers, integer_in
from federation.deploy import generate
from schemas.base import ConfigError
from schemas.federation import FederationFile, load_federation

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "deploy",
        help="generate a whole federation's configs and certificates from one file",
        formatter_class=Formatter,
        description=(
            "A federation file (labs, their endpoints and which dials which, agents,\n"
            "operators, how each lab's agents authenticate) generates every lab's router\n"
            "config (TLS, per-agent access control), every agent's and operator's Zenoh\n"
            "config, the certificates and the systemd units. Generating again keeps the CA,\n"
            "the certificates and the passwords. See docs/deploy.md."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab deploy generate deploy/federation.example.toml --out fed/\n"
            "  fedlab deploy generate federation.toml --out /tmp/fed --local   # one host\n"
            "  fedlab deploy generate federation.toml --out /tmp/fed --local --port 17447\n"
            "  fedlab deploy check federation.toml"
        ),
    )
    actions = p.add_subparsers(dest="deploy_command", required=True, metavar="ACTION")
    q = actions.add_parser(
        "generate",
        help="write DIR/ca/ and one folder per lab, DIR/<lab>/, to install as /etc/fedlab",
        formatter_class=Formatter,
        description=(
            "Write DIR/ca/ (the CA and every certificate: keep it offline) and DIR/<lab>/ for\n"
            "each lab: routers/, agents/, operators/, certs/, systemd/ and, on a password\n"
            "lab, <lab>.users. Paths inside the files point under --root (/etc/fedlab)."
        ),
        epilog="Example: fedlab deploy generate deploy/federation.example.toml --out fed/",
    )
    q.add_argument("file", type=Path, help="the federation file (TOML)")
    q.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    where = q.add_mutually_exclusive_group()
    where.add_argument(
        "--root",
        type=Path,
        default=generate.DEFAULT_ROOT,
        metavar="PATH",
        help="where each lab installs its folder (absolute)",
    )
    where.add_argument(
        "--local",
        action="store_true",
        help="run the federation on this host as generated: every path points at\n"
        "DIR/<lab>/ itself, and a lab not already on loopback listens on tls/127.0.0.1:PORT\n"
        "(dialled as tls/localhost:PORT, its certificate naming both)",
    )
    q.add_argument(
        "--port",
        type=integer_in(1, 65535, "a port"),
        metavar="N",
        help="with --local: the first lab's port, the next lab's N+1, and so on (default: "
        "each lab's own listen port, one up when an earlier lab has it)",
    )
    q.set_defaults(func=run)
    q = actions.add_parser(
        "check",
        help="validate a federation file; print its labs and links",
        formatter_class=Formatter,
        description="Validate a federation file: a bad one fails naming the field.",
        epilog="Example: fedlab deploy check deploy/federation.example.toml",
    )
    q.add_argument("file", type=Path, help="the federation file (TOML)")
    q.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    fed = load_federation(args.file)  # a ConfigError is reported by main(), exit 2
    if args.deploy_command == "check":
        return _check(args.file, fed)
    return _generate(args, fed)


def _check(path: Path, fed: FederationFile) -> int:
    for lab, entry in fed.labs.items():
        try:
            generate.access_control(fed, lab)  # its ids are unique
        except ConfigError as error:
            raise ConfigError(f"{path}: {error}") from None
        dials = f", dials {', '.join(entry.dial)}" if entry.dial else ""
        hosted = ""
        if entry.hosted:
            runs = [f"{h} runs {', '.join(names)}" for h, names in entry.hosted.items()]
            hosted = f", {len(entry.hosted)} hosted process(es) ({'; '.join(runs)})"
        print(
            f"{lab}: {entry.auth}, {len(entry.agents)} agent(s), "
            f"{len(entry.operators)} operator(s){hosted}{dials}"
        )
    return 0


def _generate(args: argparse.Namespace, fed: FederationFile) -> int:
    root: Path = args.root
    if not args.local and not root.is_absolute():
        print(f"fedlab deploy: error: --root {root}: give an absolute path", file=sys.stderr)
        return 2
    if args.port is not None and not args.local:
        print(
            "fedlab deploy: error: --port moves the labs onto loopback: give --local too",
            file=sys.stderr,
        )
        return 2
    try:
        done = generate.generate(fed, args.out, root=root, local=args.local, port=args.port)
    except (ValueError, OSError) as error:  # CertError is a ValueError
        where = f"{args.file}: " if isinstance(error, ConfigError) else ""
        print(f"fedlab deploy: error: {where}{error}", file=sys.stderr)
        return 2
    out = args.out.resolve()
    for path in done.files:
        print(path.relative_to(out))
    for path in done.removed:
        print(f"removed {path.relative_to(out)}")
    if done.issued:
        print(f"issued: {', '.join(done.issued)}")
    if args.local:
        print(f"{len(done.files)} files in {out}, to run on this host:")
        for lab, endpoint in done.listening.items():
            router = out / lab / "routers" / f"{lab}.json5"
            print(f"{lab}: its router listens on {endpoint} (fedlab router -c {router})")
        return 0
    print(
        f"{len(done.files)} files in {out}: copy {out}/<lab>/ to /etc/fedlab on that lab's "
        f"hosts; keep {out}/ca/ offline (docs/deploy.md)"
    )
    return 0
