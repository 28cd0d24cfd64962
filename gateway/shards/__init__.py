"""Shards: gateway processes that share a plant's machines, by leases with fencing tokens in PostgreSQL."""
