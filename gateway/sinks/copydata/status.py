"""A machine's COPYDATA state as gateway-owned variables, so OPC UA and MQTT show it too.

`Status/CopydataTargets`: each target's link in one line
(`nesting: tcp-server 0.0.0.0:5020 listening, 2 clients`).
`Status/CopydataFeedback`: the latest reply from the nesting software, as the
same JSON document that goes to MQTT on `<prefix>/<machine>/copydata/feedback`.
Counters stay out of these texts on purpose: they would change every second,
and MQTT folds the Status variables into one retained status document.
"""

from __future__ import annotations

from collections.abc import Callable

from gateway.model.tree import Machine

TARGETS_PATH = "Status/CopydataTargets"
FEEDBACK_PATH = "Status/CopydataFeedback"


class CopydataStatus:
    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self.targets_node = machine.add_internal(
            TARGETS_PATH, "String", "COPYDATA targets for nesting software and the state of each link", ""
        )
        self.feedback_node = machine.add_internal(
            FEEDBACK_PATH,
            "String",
            "The latest reply from the nesting software (JSON), as published on MQTT",
            "",
        )
        self._describers: list[Callable[[], str]] = []

    def add_target(self, describe: Callable[[], str]) -> None:
        self._describers.append(describe)
        self.refresh()

    def refresh(self) -> None:
        text = "; ".join(describe() for describe in self._describers)
        self.machine.set_internal(self.targets_node, text)

    def feedback(self, document: str) -> None:
        self.machine.set_internal(self.feedback_node, document)
