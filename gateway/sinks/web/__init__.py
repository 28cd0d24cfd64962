"""The web console, the REST API and /metrics, served by the gateway itself (gateway/sinks/web/config.py)."""
