"""Haas NGC machine data collection (MDC, Setting 143): Q-command queries and ?E macro writes, sans I/O."""
