"""cnc-gateway: CNC variables to OPC UA and MQTT, G-code jobs over FTP, COPYDATA frames."""

__version__ = "0.1.0"
