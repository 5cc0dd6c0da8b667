"""``decentral keys``: make the signing keys of a set of agents and the skeleton of their peers file."""

from __future__ import annotations

import argparse

__all__ = ["HELP", "add_arguments", "run"]

HELP = "make an Ed25519 key per agent (NAME.key.json, mode 0600; NAME.pub.json) and a peers.json skeleton"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("names", nargs="+", metavar="NAME", help="agent (assembly) names")
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="folder to write into (created if missing)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="host written into every peers.json address (default: 127.0.0.1; edit the file "
                             "when agents run on several machines)")
    parser.add_argument("--base-port", type=int, default=47000,
                        help="port of the first NAME in peers.json; the others count up (default: 47000)")
    parser.add_argument("--force", action="store_true", help="replace an existing key set in DIR")


def run(args: argparse.Namespace) -> int:
    from sims.cli import feedback
    from sims.io.keyfiles import write_keys

    keys = write_keys(args.output, args.names, host=args.host, base_port=args.base_port, force=args.force)
    feedback.summary(f"{len(keys.private)} key pairs and {keys.peers} written (private keys mode 0600)")
    return 0
