"""Modbus, without I/O: addresses as mappings write them, register layouts, and the request planner.

- `address`: a variable's `source` (`holding:100:float32:CDAB`, `40101`, `coil:7`, `holding:3.5`),
  parsed strictly and resolved against the variable's type into a `Field`;
- `layout`: a field's value from registers and back, in every word and byte order;
- `planner`: a polling group's fields coalesced into as few read requests as the device allows;
- `frames`: Modbus TCP frames (MBAP header and PDUs) for a server: the simulator's face and the tests'
  device, which are not the gateway's client library.

The driver (gateway/sources/modbus/) reads with pymodbus and decodes with `layout`.
"""
