"""`python -m bench.run` (`make bench`): every scenario, one table, and the same figures as JSON.

    make bench                          # the full run (about 10-15 minutes on 2 cores)
    make bench BENCH_ARGS=--quick       # a taste in about two minutes
    python -m bench.run --only mirror --quick --profile
    python -m bench.run --only peer --quick             # the gateway against Node-RED, short windows
    python -m bench.run --only dnc --quick --dnc-gateway before=/tmp/gw-old --dnc-gateway after=.

Scenarios run one after another, never side by side, each in processes of its
own; baselines first, because the later figures are judged against them.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import shutil
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

from bench.context import Context, Settings
from bench.procs import ROOT, load_average
from bench.report import Results, render
from bench.scenarios import (
    baselines,
    dnc,
    fleet,
    focas,
    jobs,
    mirror,
    mtconnect,
    naive,
    peer,
    plc,
    qos1,
    queue,
    scale,
    sparkplug,
    umati,
    web,
)
from bench.targets import judge

RESULTS = Path(__file__).resolve().parent / "results"

SCENARIOS: dict[str, Callable[[Context], Awaitable[None]]] = {
    "baselines": baselines.run,
    "mirror": mirror.run,
    "naive": naive.run,
    "peer": peer.run,
    "scale": scale.run,
    "jobs": jobs.run,
    "sparkplug": sparkplug.run,
    "mtconnect": mtconnect.run,
    "web": web.run,
    "dnc": dnc.run,
    "focas": focas.run,
    "plc": plc.run,
    "umati": umati.run,
    "queue": queue.run,
    "qos1": qos1.run,
    "fleet": fleet.run,
}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.run", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer and shorter steps (about two minutes)")
    p.add_argument(
        "--only",
        nargs="+",
        choices=list(SCENARIOS),
        metavar="SCENARIO",
        help=f"run only these scenarios: {', '.join(SCENARIOS)}",
    )
    p.add_argument(
        "--out", type=Path, default=RESULTS, help="folder for the JSON results (default bench/results)"
    )
    p.add_argument(
        "--profile",
        action="store_true",
        help="sample the gateway with py-spy during each mirror configuration's last step "
        "(flat out by default) and report where time goes",
    )
    p.add_argument("--keep", action="store_true", help="keep the work directory (logs, configs, profiles)")
    p.add_argument("--window", type=float, default=None, help="seconds per measurement window")
    p.add_argument("--sizes", type=int, nargs="+", metavar="N", help="mirror: numbers of variables")
    p.add_argument("--rates", nargs="+", metavar="R", help="mirror: changes/s per step ('max': flat out)")
    p.add_argument("--qos", type=int, nargs="+", choices=[0, 1], help="mirror: MQTT QoS levels")
    p.add_argument("--sources", nargs="+", choices=["opcua", "inproc"], help="mirror: sources")
    p.add_argument("--peer-rates", nargs="+", metavar="R", help="peer: changes/s per step ('max': flat out)")
    p.add_argument("--scale", type=int, nargs=2, metavar=("MACHINES", "PER_MACHINE"), help="scale: size")
    p.add_argument(
        "--dnc-part",
        action="append",
        default=[],
        dest="dnc_parts",
        choices=["load", "after_dc3", "single", "fleet", "restart"],
        help="dnc: run only this part (repeatable), e.g. the 10 MB after-DC3 drip alone on a quiet machine",
    )
    p.add_argument(
        "--dnc-gateway", action="append", type=_labelled, metavar="LABEL=PATH", dest="dnc_gateways",
        help="dnc: run the scenario against the gateway/ of the checkout at PATH, its figures labelled "
        "LABEL; repeat for a before/after table from one run (e.g. before=/tmp/gw-old after=.)",
    )  # fmt: skip
    return p


def _labelled(text: str) -> tuple[str, str]:
    label, sep, path = text.partition("=")
    if not sep or not label or not path:
        raise argparse.ArgumentTypeError(f"{text!r} is not LABEL=PATH")
    if not label.replace("-", "").replace("_", "").isalnum():
        raise argparse.ArgumentTypeError(f"label {label!r}: letters, digits, - and _ only")
    if not (Path(path) / "gateway" / "__init__.py").is_file():
        raise argparse.ArgumentTypeError(f"{path}: no gateway/ package there (a checkout of cnc-gateway?)")
    return label, path


def _override(settings: Settings, args: argparse.Namespace) -> None:
    if args.window:
        settings.window = args.window
    if args.sizes:
        settings.mirror_sizes = args.sizes
    if args.rates:
        settings.mirror_rates = [math.inf if r == "max" else float(r) for r in args.rates]
    if args.peer_rates:
        settings.peer_rates = [math.inf if r == "max" else float(r) for r in args.peer_rates]
    if args.qos:
        settings.mirror_qos = args.qos
    if args.sources:
        settings.mirror_sources = args.sources
    if args.scale:
        settings.scale_machines, settings.scale_per_machine = args.scale
    settings.dnc_parts = list(args.dnc_parts)
    if args.dnc_gateways:
        labels = [label for label, _path in args.dnc_gateways]
        if len(set(labels)) != len(labels):
            raise SystemExit(f"--dnc-gateway: labels must differ ({', '.join(labels)})")
        settings.dnc_gateways = [(label, path) for label, path in args.dnc_gateways]


def compile_sources() -> str:
    """Write the byte code of the gateway's and the simulator's modules, as installing a wheel does.

    With PYTHONDONTWRITEBYTECODE set (these machines set it) an editable install never writes it, and
    every process the bench starts compiled some 170 modules from source first: 0.2-0.4 s of the
    gateway's start-up that an installed gateway does not spend. Modules already current are left."""
    import compileall

    ok = all(compileall.compile_dir(ROOT / folder, quiet=1, workers=0) for folder in ("gateway", "simulator"))
    return "current" if ok else "some modules did not compile (their processes compile them at start)"


async def main(args: argparse.Namespace) -> int:
    settings = Settings.quick_run() if args.quick else Settings.full()
    settings.profile = args.profile
    _override(settings, args)
    workdir = Path(tempfile.mkdtemp(prefix="cnc-bench-"))
    results = Results(args={k: str(v) for k, v in vars(args).items()})
    ctx = Context(settings, workdir, results)
    started = time.monotonic()
    results.load["before"] = load_average()
    print(
        f"cnc-gateway benchmark ({'quick' if settings.quick else 'full'}); work directory {workdir}",
        flush=True,
    )
    compiled = compile_sources()
    print(f"byte code of gateway/ and simulator/: {compiled}", flush=True)
    results.details["byte_code"] = compiled
    try:
        for name in args.only or list(SCENARIOS):
            print(f"\n== {name}", flush=True)
            t0 = time.monotonic()
            try:
                await SCENARIOS[name](ctx)
            except Exception as exc:  # noqa: BLE001 - one broken scenario must not lose the others' figures
                results.errors.append(f"{name}: {type(exc).__name__}: {exc}")
                print(f"  FAILED: {type(exc).__name__}: {exc}", flush=True)
            results.details.setdefault("durations", {})[name] = round(time.monotonic() - t0, 1)
    finally:
        results.load["after"] = load_average()
        results.details["profiles"] = ctx.profiles
        results.details["total_seconds"] = round(time.monotonic() - started, 1)
        judge(ctx)
        print("\n" + render(results))
        _print_profiles(ctx)
        path = results.write(args.out)
        print(
            f"\nJSON: {path} (and {args.out / 'latest.json'}); load average before/after: "
            f"{results.load['before']} / {results.load['after']}; {results.details['total_seconds']:.0f} s"
        )
        if args.keep or results.errors:
            print(f"work directory kept: {workdir}")
        else:
            shutil.rmtree(workdir, ignore_errors=True)
    return 1 if results.errors else 0


def _print_profiles(ctx: Context) -> None:
    for name, prof in ctx.profiles.items():
        if prof and "pyinstrument" in prof:
            print(f"\nWhere the time goes ({name}; pyinstrument):")
            print("\n".join(prof["pyinstrument"][:40]))
            continue
        if not prof or "own" not in prof:
            continue
        print(f"\nWhere the gateway's time goes ({name}; py-spy, {prof['samples']} samples), own time:")
        for func, share in prof["own"][:12]:
            print(f"  {share:5.1f} %  {func}")
        if prof.get("parts"):
            native = "with native frames" if prof.get("native") else "Python frames only"
            print(f"  by part ({prof['parts_samples']} samples of every thread, {native}):")
            for part, share in prof["parts"].items():
                print(f"  {share:5.1f} %  {part}")


if __name__ == "__main__":
    sys.exit(asyncio.run(main(build_parser().parse_args())))
