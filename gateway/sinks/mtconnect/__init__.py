"""The MTConnect agent face: the mirror as an MTConnect 2.4 agent over HTTP (see sink.py)."""

from __future__ import annotations

from gateway.settings.mtconnect import VariableMTConnect
from gateway.settings.sections import Section
from gateway.sinks.base import Sink, SinkContext, SinkSpec
from gateway.sinks.mtconnect.config import AgentConfig

SECTION = Section("mtconnect", AgentConfig)


def _create(context: SinkContext) -> Sink | None:
    config = context.section(SECTION)
    if config is None:  # the MTConnect agent (HTTP), when asked for
        return None
    from gateway.sinks.mtconnect.sink import MTConnectSink

    return MTConnectSink(context.tree, config, context.mappings, context.state_dir)


SPEC = SinkSpec(
    name="mtconnect",
    summary="an MTConnect 2.4 agent over HTTP: probe, current, sample streams, assets (aiohttp)",
    create=_create,
    section=SECTION,
    variable_sections=(Section("mtconnect", VariableMTConnect),),
)
