"""`cnc-gateway hash-password`: the scrypt hash to put in the gateway file instead of a password."""

from __future__ import annotations

import argparse
import getpass
import sys

from gateway.auth.known_passwords import is_known
from gateway.auth.passwords import hash_password


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "hash-password", help="print the hash of a password, for users and inbox accounts (password_hash)"
    )
    p.add_argument(
        "--stdin", action="store_true", help="read the password from the first line of standard input"
    )
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    if args.stdin or not sys.stdin.isatty():
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = getpass.getpass("password: ")
        if getpass.getpass("again: ") != password:
            print("error: the passwords differ", file=sys.stderr)
            return 1
    if not password:
        print("error: empty password", file=sys.stderr)
        return 1
    if is_known(password):
        print(
            f"error: {password!r} is published in cnc-gateway's docs and examples; the gateway refuses it at "
            "start-up: choose another",
            file=sys.stderr,
        )
        return 1
    print(hash_password(password))
    return 0
