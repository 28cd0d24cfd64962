"""Helper processes of the benchmark: each runs one party (simulator, gateway, subscriber, ...) on its own.

Every party runs in its own process so that its CPU time and memory are its own,
and the orchestrator drives them over stdin/stdout (`protocol.py`).
"""
