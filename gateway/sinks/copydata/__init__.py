"""COPYDATA frames for nesting software: emitters, transports, replies.

Per configured target (mapping file, `copydata.targets`), an `Emitter` turns
the machine's changes into frames (gateway.codecs.copydata) and hands them to
one bounded `Channel` per receiver; a transport (TCP client or server, UDP,
or WM_COPYDATA on Windows) drains the channels and feeds what comes back to
`Feedback`. `CopydataSink` runs them all. Transports see only the emitter's
port (`port.TransportPort`); `sink.make_transport` picks one per target (the
win32 one exists only on Windows).
"""

from __future__ import annotations

from gateway.settings.sections import Section
from gateway.sinks.base import Sink, SinkContext, SinkSpec
from gateway.sinks.copydata.config import MachineCopydata, VariableCopydata

MACHINE = Section("copydata", MachineCopydata)


def _create(context: SinkContext) -> Sink | None:
    if not any(m.section(MACHINE) is not None for m in context.mappings.values()):
        return None  # no machine sends frames to nesting software
    from gateway.sinks.copydata.sink import CopydataSink

    return CopydataSink(context.tree, context.mappings)


SPEC = SinkSpec(
    name="copydata",
    summary="COPYDATA frames for nesting software: tcp-client, tcp-server, udp, win32 (WM_COPYDATA)",
    create=_create,
    machine_sections=(MACHINE,),
    variable_sections=(Section("copydata", VariableCopydata),),
)
