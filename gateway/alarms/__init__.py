"""Machine alarms: the controller's active list turned into occurrences with history, acknowledgement
and confirmation (stored in SQLite), told to the sinks (OPC UA conditions, MQTT topics)."""
