"""The MTConnect agent face: the mirror as an MTConnect 2.4 agent over HTTP (see sink.py)."""
