"""MTConnect in: machines read from another agent (agent_source.py) or straight from an SHDR adapter
(shdr_source.py); `discover.py` writes a starting mapping from an agent's /probe."""
