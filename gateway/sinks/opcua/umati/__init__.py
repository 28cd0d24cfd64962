"""The umati view: every machine with a `umati:` section also served as an OPC 40501-1 MachineTool.

config.py is the section's model (loaded with the mapping files, without asyncua's server); install.py
is the ServerExtension, model.py and instance.py read the official types (nodesets/, vendored with their
licence, see nodesets/SOURCES.md) and plan each instance. gateway/sinks/opcua/extensions.py names it.
"""
