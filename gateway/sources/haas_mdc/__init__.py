"""The Haas NGC machine data collection driver (`driver: {type: haas-mdc}`)."""
