"""The Modbus TCP driver: `link.py` is the one module that imports pymodbus (errors translated there),
`source.py` polls the device's groups and carries out writes (docs/architecture.md, "Modbus")."""
