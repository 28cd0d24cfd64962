"""The simulator's FOCAS2 Ethernet face (port 8193): the laser as a Fanuc sees it, for the FOCAS driver."""

from simulator.focas.face import DEFAULT_PORT, DEFAULT_SESSIONS, FocasFace

__all__ = ["DEFAULT_PORT", "DEFAULT_SESSIONS", "FocasFace"]
