"""Faces of third-party libraries that several parts share: typed where a library's annotations are
narrower than what it accepts, and patched where one of its habits costs too much.

Stateless and without I/O of their own; they import their library and nothing of the gateway, so the
adapters of every layer and the simulator may use them (docs/architecture.md, "Layers").
"""
