"""The per-machine builder: each machine's delivery, worker, auto-start and `Programs` methods, with
what they need passed in as they are made.

A machine's `jobs.controller.type` picks its transport's spec (gateway/transports/registry.py); the
spec assembles all of that type's machines at once (serial lines share one drip-feed fleet) from the
narrow ports the core gives it (`MachineJobs`, `CorePorts`). Nothing here knows a transport by name.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path

from gateway.config.jobs import JobsConfig
from gateway.config.validation import ValidationRules
from gateway.jobs.backups import BackupShelf
from gateway.jobs.delivery.autostart import AutoStarter
from gateway.jobs.delivery.fetch import ProgramFetch
from gateway.jobs.delivery.supervisor import DeliverySupervisor
from gateway.jobs.delivery.worker import DeliveryWorker, LeaseView
from gateway.jobs.intake import Intake
from gateway.jobs.programs import program_methods
from gateway.jobs.queue_port import QueuePort
from gateway.jobs.spool import Spool
from gateway.jobs.threads import JobThreads
from gateway.jobs.validation.pipeline import validate_program
from gateway.model.tree import VariableTree
from gateway.transports import registry
from gateway.transports.base import CorePorts, MachineJobs, ProgramVerdict, Validate


def validator(rules: ValidationRules) -> Validate:
    """The validation port a transport gets: a machine's rules, the verdict cut to what it reads."""

    def validate(data: bytes, filename: str) -> ProgramVerdict:
        verdict = validate_program(data, filename, rules)
        reason = verdict.rejections[0].reason if verdict.rejections else ""
        return ProgramVerdict(verdict.accepted, reason, verdict.program)

    return validate


def assemble_machines(
    tree: VariableTree,
    machines: Mapping[str, JobsConfig],
    *,
    state_dir: Path,
    backups_dir: Path,
    threads: JobThreads,
    spool: Spool,
    supervisor: DeliverySupervisor,
    intake: Intake,
    port: QueuePort,
    lease: LeaseView | None = None,
) -> dict[str, BackupShelf]:
    """Builds every machine's delivery into `supervisor` and adds its methods to the tree; returns each
    machine's backup shelf (Programs.Backup)."""
    core = CorePorts(
        state_dir=state_dir,
        backups_dir=backups_dir,
        work=threads.work,
        queue_thread=threads.queue,
        submit=intake.submit_request,
        find_job=intake.find_requested,
    )
    by_type: dict[str, list[MachineJobs]] = {}
    for name, jobs in machines.items():
        by_type.setdefault(jobs.controller.type, []).append(
            MachineJobs(
                name=name,
                machine=tree.machines[name],
                jobs=jobs,
                validate=validator(jobs.validation),
                restart=functools.partial(port.restart_job, machine=name),
            )
        )
    for kind, group in by_type.items():
        deliveries = registry.find(kind).assemble(group, core)
        supervisor.transports[kind] = deliveries
        supervisor.deliveries.update(deliveries.machines)
    # A program another shard took in is read from the queue's database, where the queue carries them.
    fetch = ProgramFetch(supervisor.queue, threads.work) if supervisor.queue.shares_programs else None
    return {
        name: build_machine(
            tree,
            name,
            jobs,
            supervisor=supervisor,
            spool=spool,
            intake=intake,
            backups=backups_dir,
            fetch=fetch,
            lease=lease,
        )
        for name, jobs in machines.items()
    }


def build_machine(
    tree: VariableTree,
    name: str,
    jobs: JobsConfig,
    *,
    supervisor: DeliverySupervisor,
    spool: Spool,
    intake: Intake,
    backups: Path,
    fetch: ProgramFetch | None = None,
    lease: LeaseView | None = None,
) -> BackupShelf:
    """One machine's worker (with its transport and auto-start) and its `Programs` methods."""
    machine = tree.machines[name]
    delivery = supervisor.deliveries[name]
    if delivery.keep_delivered > 0:
        spool.keep[name] = delivery.keep_delivered
    autostart = None if jobs.auto is None else AutoStarter(machine, jobs.auto, delivery.folder)
    worker = DeliveryWorker(
        name,
        jobs,
        supervisor.queue,
        spool,
        supervisor.publisher,
        supervisor.q,
        delivery.transport,
        autostart=autostart,
        fetch=fetch,
        lease=lease,
    )
    supervisor.add(name, worker, autostart)
    shelf = BackupShelf(backups / name, jobs.backups)
    for method in program_methods(name, store=delivery.store, submit=intake.submit_bytes, backups=shelf):
        machine.add_method(method)
    return shelf
