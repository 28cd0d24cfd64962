"""The web console, the REST API and /metrics, served by the gateway itself (gateway/sinks/web/config.py)."""

from __future__ import annotations

from gateway.settings.sections import Section
from gateway.sinks.base import Sink, SinkContext, SinkSpec
from gateway.sinks.web.config import HttpConfig

SECTION = Section("http", HttpConfig)


def _create(context: SinkContext) -> Sink | None:
    """The console reaches the job queue, the alarms, the audit table and the OPC UA trust list only
    through the ports of gateway/sinks/ports.py (`http: null` turns it off)."""
    http = context.section(SECTION)
    if http is None:
        return None
    from gateway.sinks.ports import Ports
    from gateway.sinks.web.sink import WebSink

    ports = Ports(
        gateway=context.host,
        jobs=context.jobs,
        alarms=context.alarms,
        audit=context.audit,
        trust=context.offered.trust,
    )
    return WebSink(context.tree, context.config, http, ports, logins=context.logins)


SPEC = SinkSpec(
    name="web",
    summary="the web console, the REST API, /metrics, /healthz and /readyz (aiohttp)",
    create=_create,
    section=SECTION,
)
