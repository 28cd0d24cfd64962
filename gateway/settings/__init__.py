"""The parts every settings model is built of, below every adapter and below the files that assemble them.

`gateway/config/` assembles the mapping file and the gateway file from the adapters' own models (each
in its adapter's folder, found through the registries: gateway/sources/registry.py, ...). Those models
import only this package (and their own folder), never `gateway.config`: the assembly imports them.
"""
