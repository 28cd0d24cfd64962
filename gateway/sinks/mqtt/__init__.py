"""MQTT: the variable tree as topics, liveness, store-and-forward and write-back (paho-mqtt)."""
