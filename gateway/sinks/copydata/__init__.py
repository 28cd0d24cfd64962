"""COPYDATA frames for nesting software: emitters, transports, replies.

Per configured target (mapping file, `copydata.targets`), an `Emitter` turns
the machine's changes into frames (gateway.codecs.copydata) and hands them to
one bounded `Channel` per receiver; a transport (TCP client or server, UDP,
or WM_COPYDATA on Windows) drains the channels and feeds what comes back to
`Feedback`. `CopydataSink` runs them all. Transports see only the emitter's
port (`port.TransportPort`); `sink.make_transport` picks one per target (the
win32 one exists only on Windows).
"""
