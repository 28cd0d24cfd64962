"""The MQTT link below the MQTT and the Sparkplug sink: what both stand on, written once.

Not a sink (no SinkSpec): the registry lists only the sinks. `client.py` is the paho adapter
(connect off the loop, reconnect, TLS, the will, errors as BrokerError); `broker.py` the broker keys
of the gateway file that `mqtt:` and `sparkplug.broker` share; `buffer.py` store-and-forward (the
`Backlog` and its SQLite `Journal`); `requests.py` the bounds and the log quota of requests from
the broker. The two sinks import from here and never from each other (pyproject.toml's
mqtt-sinks-independent contract), as Telegraf's outputs share plugins/common/mqtt.
"""
