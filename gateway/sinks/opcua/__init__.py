"""The OPC UA server sink: `Objects/Machines/<machine>/...` for SCADA clients."""

from gateway.sinks.opcua.server import OpcUaSink

__all__ = ["OpcUaSink"]
