"""`cnc-gateway schema`: the JSON Schema of the mapping (or gateway) file format, for editors."""

from __future__ import annotations

import argparse
import json
from typing import Any

from gateway.config.gateway import GatewayConfig
from gateway.config.mapping import MachineMapping


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("schema", help="print the JSON Schema of the mapping file format")
    p.add_argument("--gateway", action="store_true", help="the gateway file's schema instead")
    p.set_defaults(handler=handle)


def schema(gateway: bool = False) -> dict[str, Any]:
    model = GatewayConfig if gateway else MachineMapping
    out = model.model_json_schema(mode="validation")
    out["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    out["title"] = "cnc-gateway gateway file" if gateway else "cnc-gateway mapping file"
    return out


def handle(args: argparse.Namespace) -> int:
    print(json.dumps(schema(args.gateway), indent=2, sort_keys=True))
    return 0
