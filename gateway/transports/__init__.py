"""Delivery transports: how programs reach a machine's controller, one folder per transport (registry.py)."""
