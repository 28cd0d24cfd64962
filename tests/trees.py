"""A variable tree built from mapping models that keeps them, for tests that also build components.

The gateway builds the tree from the model's definitions (`MachineMapping.definition()`)
and hands each component the mappings it reads (gateway/app.py); a test that builds a
tree and then a sink, a source or a service passes `tree.mappings` the same way.
"""

from __future__ import annotations

from collections.abc import Iterable

from gateway.config.mapping import MachineMapping
from gateway.model.tree import VariableTree


class MappedTree(VariableTree):
    def __init__(self, mappings: Iterable[MachineMapping] = ()) -> None:
        listed = list(mappings)
        super().__init__(m.definition() for m in listed)
        self.mappings: dict[str, MachineMapping] = {m.machine: m for m in listed}
