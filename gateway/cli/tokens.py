"""`cnc-gateway tokens create|list|revoke`: API tokens for the web console's REST API.

Tokens are kept hashed in `<state_dir>/http-tokens.json` (gateway/auth/tokens.py); a
running gateway picks up new and revoked tokens at the next request. A token acts
with its user's role in the gateway file, so `create` checks the user there when
it is given the gateway file (-c).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gateway.auth.tokens import TokenError, TokenStore, tokens_path
from gateway.cli.state_dir import load_config, resolve_state_dir


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("tokens", help="API tokens for the REST API (kept hashed in the state directory)")
    tokens = p.add_subparsers(dest="tokens_command", metavar="ACTION", required=True)

    def common(q: argparse.ArgumentParser) -> None:
        q.add_argument(
            "-c",
            "--config",
            type=Path,
            action="append",
            metavar="FILE",
            help="the gateway file (to find its state directory and check the user)",
        )
        q.add_argument("--state-dir", type=Path, default=None, help="the gateway's state directory")

    q = tokens.add_parser("create", help="make a token for a user; it is printed once, never stored")
    common(q)
    q.add_argument("--user", required=True, help="a user of the gateway file; the token acts with its role")
    q.add_argument("--label", default="", help="what the token is for (shown by `tokens list`)")
    q.set_defaults(handler=handle_create)

    q = tokens.add_parser("list", help="the tokens: id, user, created, label (never the secret)")
    common(q)
    q.set_defaults(handler=handle_list)

    q = tokens.add_parser("revoke", help="remove a token by its id")
    common(q)
    q.add_argument("id", help="the token's id (8 hex digits, from `tokens list`)")
    q.set_defaults(handler=handle_revoke)


def _store(args: argparse.Namespace) -> TokenStore:
    return TokenStore(tokens_path(resolve_state_dir(args, "tokens", tokens_path)))


def handle_create(args: argparse.Namespace) -> int:
    config = load_config(args)
    if config is not None and args.user not in {u.name for u in config.gateway.users}:
        names = ", ".join(u.name for u in config.gateway.users) or "none"
        print(f"error: {args.user!r} is not a user of the gateway file (users: {names})", file=sys.stderr)
        return 2
    store = _store(args)
    try:
        token = store.create(args.user, args.label)
    except (TokenError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(token)
    print(
        f"(a token for {args.user}, stored hashed in {store.path}; "
        "send it as `Authorization: Bearer <token>`;"
        " it is not shown again)",
        file=sys.stderr,
    )
    return 0


def handle_list(args: argparse.Namespace) -> int:
    try:
        entries = _store(args).entries()
    except TokenError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for e in entries:
        print(f"{e.id}  {e.user:<16}  {e.created}  {e.label}")
    if not entries:
        print("no tokens", file=sys.stderr)
    return 0


def handle_revoke(args: argparse.Namespace) -> int:
    try:
        entry = _store(args).revoke(args.id)
    except (TokenError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"revoked {entry.id} ({entry.user})")
    return 0
