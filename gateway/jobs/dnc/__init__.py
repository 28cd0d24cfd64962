"""Serial DNC for jobs: one owner per serial line (send, drip-feed control, idle listening)."""
