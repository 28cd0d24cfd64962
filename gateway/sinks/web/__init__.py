"""The web console, the REST API and /metrics, served by the gateway itself (gateway/config/http.py)."""
