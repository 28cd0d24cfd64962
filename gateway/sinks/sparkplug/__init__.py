"""The Sparkplug B sink: the gateway as one edge node, every machine one of its devices.

`sink.py` runs the session (connect with the NDEATH will, births, data, deaths, store-and-forward
gated by the primary host's STATE); `devices.py` turns the tree into metrics; `node.py` holds the
edge node's own metrics; `commands.py` carries NCMD and DCMD out through the tree's one write path;
`bdseq.py` keeps the birth/death number across restarts. Payloads and topics come from the pure
codec, gateway/codecs/sparkplug/; the MQTT connection is gateway/sinks/mqtt/client.py's.
"""
