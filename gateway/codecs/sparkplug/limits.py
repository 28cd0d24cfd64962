"""The codec's size limit, apart from wire.py: the configuration checks it without loading protobuf."""

from __future__ import annotations

# Commands are a handful of metrics; anything this large is not a command we carry out.
MAX_PAYLOAD = 1 << 20
