"""Delivery: the per-machine workers that move queued jobs to a controller, through a delivery transport."""
