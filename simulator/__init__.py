"""cnc-simulator: a simulated laser cutter with an OPC UA server and an FTP program store (README.md)."""
