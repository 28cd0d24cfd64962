"""One asyncua habit the gateway cannot afford: a deep copy of every value, per subscribed item, per change.

For every value written to a node that a client monitors, asyncua's server calls
`MonitoredItemValues.set_current_datavalue`, which keeps a `copy.deepcopy` of the
DataValue, so that a caller who mutates a value after writing it cannot change
what the next change is compared against. Profiles of the mirror benchmark
(bench/README.md) put that copy at about half of the gateway's CPU time per
change when one client subscribes, more than everything else the gateway does
for the change together.

Nobody here mutates a written DataValue: the OPC UA sink builds a fresh one for
every write (gateway/sinks/opcua/values.py), and so do asyncua's own writes and
the simulator. `keep_written_values()` makes asyncua keep a reference instead of
a copy. It is process-wide (asyncua has no per-server hook), idempotent, and
leaves the comparison itself (value, status, timestamps) exactly as it was.
"""

from __future__ import annotations

from typing import Any

_MARK = "_cnc_gateway_keeps_reference"


def keep_written_values() -> None:
    """Replace asyncua's deep copy of each monitored value by a reference (once per process)."""
    from asyncua.server.monitored_item_service import MonitoredItemValues

    if getattr(MonitoredItemValues, _MARK, False):
        return

    def set_current_datavalue(self: Any, cur_val: Any) -> None:
        self.old_dvalue = self.current_dvalue
        self.current_dvalue = cur_val

    MonitoredItemValues.set_current_datavalue = set_current_datavalue  # type: ignore[method-assign]
    setattr(MonitoredItemValues, _MARK, True)
