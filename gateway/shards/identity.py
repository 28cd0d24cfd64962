"""Which shard of a fleet this process is, from the environment `cnc-gateway fleet` gives each shard.

What must differ between the shards of one host and stay the same across a shard's restarts (an MQTT
client id, whose persistent session the restarted shard resumes; the gateway's own status topic; an OPC
UA application URI) takes the shard's number from here: `CNC_SHARD_INDEX`, else the K of `CNC_SHARD`
when it reads K/N. None: not a shard of a fleet.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from gateway.shards.static import parse_k_of_n


def shard_index(environ: Mapping[str, str] | None = None) -> int | None:
    env = os.environ if environ is None else environ
    given = env.get("CNC_SHARD_INDEX", "").strip()
    if given.isdigit():
        return int(given)
    try:
        return parse_k_of_n(env.get("CNC_SHARD", "")).k
    except ValueError:
        return None


def fleet_size(environ: Mapping[str, str] | None = None) -> int | None:
    """The N of `CNC_SHARD` = K/N (None: not a shard of a fleet)."""
    env = os.environ if environ is None else environ
    try:
        return parse_k_of_n(env.get("CNC_SHARD", "")).n
    except ValueError:
        return None
