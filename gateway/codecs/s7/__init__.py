"""Siemens S7 (S7comm), without I/O: addresses as STEP 7 writes them, the elementary types' layouts, and
the multi-variable read and write PDUs, planned within the PDU size the PLC negotiated.

- `address`: `DB10.DBD4`, `DB10.DBX2.3`, `MW20`, `I0.1`, `Q4.0`, `DB5.DBB20:STRING[30]`, parsed
  strictly and resolved against the variable's type into a `Field`;
- `layout`: a field's value from the bytes the PLC answered, and back (BOOL ... LREAL, STRING with its
  two-byte header, DATE_AND_TIME in BCD);
- `pdu`: the plan (fields coalesced into items, items packed into requests that fit the PDU both ways)
  and the Read Var / Write Var request and response PDUs, item by item.

The driver (gateway/sources/s7/) exchanges these PDUs over python-snap7's ISO-on-TCP connection.
"""
