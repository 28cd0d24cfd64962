"""Which state directory a reading command (jobs, alarms, audit) opens when it is not told.

The one given with --state-dir, else the gateway file's (-c), else
$CNC_GATEWAY_STATE_DIR, else whichever of ./state (`cnc-gateway run`) and
./state/demo (`make demo`) holds the newest store of the kind asked for.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path

from gateway.cli.check import report_config_error
from gateway.config.loader import Config, load
from gateway.errors import ConfigError

DEFAULT_STATE_DIRS = (Path("state"), Path("state/demo"))


def add_state_dir_options(parser: argparse.ArgumentParser) -> None:
    """-c/--config and --state-dir, which `resolve_state_dir` reads."""
    parser.add_argument(
        "-c",
        "--config",
        type=Path,
        action="append",
        metavar="FILE",
        help="gateway or mapping file(s) the gateway runs with (to find its state directory)",
    )
    parser.add_argument("--state-dir", type=Path, default=None, help="the gateway's state directory")


def load_config(args: argparse.Namespace) -> Config | None:
    """The gateway file given with -c (None without one); exits 2 after reporting a bad one."""
    if not args.config:
        return None
    try:
        return load(args.config)
    except ConfigError as exc:
        report_config_error(exc)
        raise SystemExit(2) from None


def resolve_state_dir(
    args: argparse.Namespace,
    label: str,
    store: Callable[[Path], Path],
    last_written: Callable[[Path], float] | None = None,
) -> Path:
    """The state directory to read; `store(dir)` is the file that marks one in use, named as `label`."""
    if args.state_dir is not None:
        return Path(args.state_dir)
    config = load_config(args)
    if config is not None:
        return config.state_dir
    env = os.environ.get("CNC_GATEWAY_STATE_DIR")
    if env:
        return Path(env)
    found = [d for d in DEFAULT_STATE_DIRS if store(d).is_file()]
    if not found:
        return DEFAULT_STATE_DIRS[0]
    chosen = max(found, key=last_written or (lambda d: store(d).stat().st_mtime))
    print(f"({label}: {store(chosen)}; -c FILE or --state-dir to choose)", file=sys.stderr)
    return chosen


def audit_where(args: argparse.Namespace) -> Path | str:
    """The audit table a command reads or writes: the gateway file's `audit:` database (-c), else the
    SQLite file of the state directory `resolve_state_dir` finds."""
    from gateway.audit.store import audit_path

    if args.state_dir is None:
        config = load_config(args)
        if config is not None:
            return config.gateway.audit or audit_path(config.state_dir)
    return audit_path(resolve_state_dir(args, "audit", audit_path))
