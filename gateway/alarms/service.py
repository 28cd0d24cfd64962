"""AlarmService: the alarm managers of every machine with an `alarms:` section, and their history file.

Entered before the sinks (so that the OPC UA server finds the occurrences a
previous run left open and can offer them to ConditionRefresh from the start),
run with the other components: one task per machine (`alarms:<machine>`).
SQLite calls run in one worker thread of the service's own, off the event loop.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Protocol, Self, TypeVar

from gateway.alarms.config import AlarmsConfig
from gateway.alarms.manager import AlarmManager, UnknownAlarm
from gateway.alarms.store import history_at
from gateway.errors import AlarmStoreError, SinkError
from gateway.model.context import WriteContext
from gateway.model.tree import VariableTree

log = logging.getLogger("gateway.alarms")

T = TypeVar("T")


class AlarmsMapping(Protocol):
    """What the alarm managers read of a machine's mapping (gateway/config/mapping.py MachineMapping fits)."""

    @property
    def alarms(self) -> AlarmsConfig | None: ...

    @property
    def variables(self) -> Sequence[Any]: ...


class AlarmService:
    def __init__(
        self,
        tree: VariableTree,
        mappings: Mapping[str, AlarmsMapping],
        state_dir: Path,
        database: str | None = None,
    ) -> None:
        self.tree = tree
        self.store = history_at(database, state_dir)  # `database`: the gateway file's alarm_history
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="alarms-db")
        self.managers: dict[str, AlarmManager] = {
            name: AlarmManager(tree.machines[name], mapping.alarms, self.store, self.db, mapping.variables)
            for name, mapping in mappings.items()
            if mapping.alarms is not None
        }
        self._opened = False

    async def db(self, fn: Callable[..., T], *args: Any) -> T:
        """Run a store call in the service's database thread."""
        return await asyncio.get_running_loop().run_in_executor(self._pool, functools.partial(fn, *args))

    async def __aenter__(self) -> Self:
        try:
            await self.db(self.store.open)
        except AlarmStoreError as exc:
            raise SinkError(str(exc)) from None
        self._opened = True
        for name, manager in self.managers.items():
            records = await self.db(self.store.retained, name)
            manager.load(records)
            if records:
                log.info("%s: %d alarm(s) still listed from the previous run", name, len(records))
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._opened:
            self._opened = False
            await self.db(self.store.close)
        await asyncio.to_thread(self._pool.shutdown, True)

    # --- the web console's port (gateway/sinks/ports.py AlarmsPort) ----------------------------

    @property
    def alarm_machines(self) -> list[str]:
        return sorted(self.managers)

    def active_alarms(self, machine: str | None = None) -> list[dict[str, Any]]:
        """The retained occurrences (active, or waiting for an acknowledgement or confirmation)."""
        managers = [self.managers[machine]] if machine in self.managers else []
        if machine is None:
            managers = list(self.managers.values())
        return [{"machine": m.name, **r.as_dict()} for m in managers for r in m.retained()]

    async def alarm_history(self, machine: str | None, limit: int) -> list[dict[str, Any]]:
        records = await self.db(functools.partial(self.store.history, machine, limit=limit))
        return [{"machine": r.machine, **r.as_dict()} for r in records]

    def acknowledge_role(self, machine: str) -> str | None:
        manager = self.managers.get(machine)
        return None if manager is None else manager.config.acknowledge_role

    async def acknowledge_alarm(
        self, machine: str, occurrence: int, ctx: WriteContext, comment: str
    ) -> dict[str, Any]:
        record = await self._manager(machine).acknowledge(occurrence, ctx, comment)
        return {"machine": machine, **record.as_dict()}

    async def confirm_alarm(
        self, machine: str, occurrence: int, ctx: WriteContext, comment: str
    ) -> dict[str, Any]:
        record = await self._manager(machine).confirm(occurrence, ctx, comment)
        return {"machine": machine, **record.as_dict()}

    def _manager(self, machine: str) -> AlarmManager:
        manager = self.managers.get(machine)
        if manager is None:
            raise UnknownAlarm(f"{machine!r} has no alarms")
        return manager

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tg:
            for name, manager in self.managers.items():
                tg.create_task(manager.run(), name=f"alarms:{name}")
