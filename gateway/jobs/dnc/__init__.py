"""Serial DNC in the gateway: the transfer log, the idle line's listener (punches, remote requests)."""
