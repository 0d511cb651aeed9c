"""The ``swarm`` command line (click): run, world, agent, record, metrics, view.

``swarm run`` validates the config before anything starts, writes the resolved config
into the run folder, starts the recorder, one process per agent and the world (each in
its own process group), shows progress from the world's status messages, and stops
everything when the scenario ends, on Ctrl-C, or when the world or the recorder dies.
An agent that dies is reported (``lost_agents``) while the others fly on (docs/design.md,
"Failures"); ``--stop-on-agent-death`` stops the whole run instead.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from swarm.config import ConfigError, ScenarioConfig, dump, load
from swarm.errors import InputError
from swarm.proctitle import name_process
from swarm.shutdown import StopSignals


def _overrides(mode: str | None, port: int | None = None) -> dict[str, Any]:
    over: dict[str, Any] = {}
    if mode:
        over["time"] = {"mode": mode}
    if port is not None:
        over["network"] = {"port": port}
    return over


def _load_or_exit(path: str, over: dict[str, Any]) -> ScenarioConfig:
    try:
        return load(path, over)
    except ConfigError as exc:
        click.echo(f"config error: {exc}", err=True)
        sys.exit(2)


_SECRETS = click.option(
    "--secrets",
    type=click.Path(file_okay=False, path_type=Path),
    help="the run's credentials folder (swarm run makes one; swarm secrets writes one)",
)


def _console(stderr: bool = False) -> Any:
    """A rich console that never cuts a line: off a terminal (a log, CI, a pipe) as wide as
    a line needs (rich would take 80 columns, or ``COLUMNS``)."""
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    if stream.isatty():
        return Console(stderr=stderr)
    return Console(stderr=stderr, width=100_000, soft_wrap=True)


def _world_landed(out: Path) -> bool:
    """Whether the world of the run in ``out`` took a land request (its summary line)."""
    from swarm.ledger import summaries

    return summaries(out / "logs").get("world", {}).get("landing_from_s") is not None


def _status_info(st: dict[str, Any]) -> str:
    """The progress bar's line for the world's status message (min sep in mm)."""
    sep = f"{1e3 * st['min_sep']:.0f} mm" if st["min_sep"] < 1e8 else "-"
    info = f"rtf {st['rtf']:.2f}  min sep {sep}  infeasible {st['infeasible']}  coll {st['collisions']}"
    if st.get("stalls"):
        info += f"  [yellow]stalls {st['stalls']}[/]"
    if st.get("fallback_ids"):
        info += f"  [yellow]plugin fallbacks {int(sum(st['fallback_ticks']))}[/]"
    if st.get("acting"):
        info += f"  [yellow]monitor: {st['acting']} acting[/]"
    if st.get("dead"):
        info += f"  [red]dead {','.join(st['dead'])}[/]"
    return info


def run_scenario(
    cfg: ScenarioConfig,
    out: Path,
    *,
    gui: bool = False,
    progress: bool = True,
    stop_on_agent_death: bool = False,
    run_id: str | None = None,
    secrets: Path | None = None,
    live_port: int | None = None,
) -> tuple[int, dict[str, Any]]:
    """Run a whole scenario as separate processes with a progress bar; (exit code, metrics).

    The first stop signal (Ctrl-C, SIGTERM, SIGHUP) lands every drone and ends the run when
    they are down (``swarm.landing``; exit code 1, ``stop_reason`` "landed on request"); a
    second one, or one before the world has ticked, stops every process at once: the
    emergency stop (real drones' motors off where they fly; ``stop_reason`` "interrupted")."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Column

    from swarm.landing import LANDED, LANDING_BANNER, LANDING_NOW, Stop, stop_for
    from swarm.runs.launch import RunHandle

    click.echo(LANDING_BANNER, err=True)
    with StopSignals() as interrupted:
        handle = RunHandle.start(
            cfg, out, gui=gui, run_id=run_id, cancelled=lambda: interrupted.now, secrets=secrets, live_port=live_port
        )
        wrap = Column(no_wrap=False, overflow="fold")  # (a narrow terminal wraps the line, never cuts it)
        bar = Progress(
            TextColumn("[bold]{task.description}", table_column=Column(no_wrap=False, overflow="fold")),
            BarColumn(bar_width=20),
            TextColumn("{task.completed:.1f}/{task.total:.1f} s sim", table_column=Column(no_wrap=True)),
            TextColumn("{task.fields[info]}", table_column=wrap),
            TimeElapsedColumn(),
            disable=not progress,
            console=_console(stderr=True),
        )
        limit = time.monotonic() + handle.wall_limit_s
        reason: str | None = None
        info = ""
        asked_s: float | None = None  # wall time of the last land request
        try:
            with bar:
                task = bar.add_task(cfg.name, total=cfg.duration_s, info="starting")
                while reason is None:
                    reason = handle.poll(stop_on_agent_death, wait_s=0.05)
                    if handle.progress.status:
                        info = _status_info(handle.progress.status) + ("  [yellow]landing[/]" if asked_s else "")
                        bar.update(task, completed=min(handle.progress.t_s, cfg.duration_s), info=info)
                    what = stop_for(interrupted.count, bool(handle.progress.status))
                    now = time.monotonic()
                    if reason == "completed" and asked_s is not None and _world_landed(out):
                        reason = LANDED
                    elif reason is None and what is Stop.NOW:
                        reason = "interrupted"
                    elif reason is None and what is Stop.LAND and (asked_s is None or now - asked_s > 1.0):
                        if asked_s is None:
                            bar.console.print(LANDING_NOW, markup=False, highlight=False)
                            limit = now + 20.0 * cfg.time.land_timeout_s + 60.0
                        handle.land("Ctrl-C")  # (repeated each second: each process takes the first)
                        asked_s = now
                    if reason is None and time.monotonic() > limit:
                        reason = "wall-clock limit"
                t_end = handle.progress.t_s
                if reason == "completed" and 0 < t_end < cfg.duration_s:  # ended early: every goal reached, or a script
                    why = "ended by the script" if cfg.script.enabled else "all goals reached"
                    bar.update(task, total=t_end, completed=t_end, info=f"{info}  ({why})")
        finally:
            handle.finish(reason or "interrupted")
    return (0 if handle.reason == "completed" else 1), handle.result


def print_summary(metrics: dict[str, Any]) -> None:
    """``swarm run``'s summary of a run's ``metrics.json``: the run's figures and one row per
    agent, each table with its metrics' meanings under it (``swarm.runs.readable``)."""
    from swarm.offline.metrics import SUMMARY_KEYS
    from swarm.runs.readable import fig, notes, print_table

    print_table("run", ["metric", "value"], [[k, fig(metrics.get(k), k)] for k in SUMMARY_KEYS], notes(SUMMARY_KEYS))
    cols = ("reached_goal", "time_to_goal_s", "path_length_m", "min_h", "min_row_h", "infeasible_ticks")
    rows = []
    for aid, a in metrics["agents"].items():
        acted = {n: c for n, c in (a.get("monitor") or {}).get("action_ticks", {}).items() if c}
        monitor = ", ".join(f"{n} {c}" for n, c in acted.items()) or "-"
        rows.append([aid, *(fig(a.get(k), k) for k in cols), monitor])
    print_table("agents", ["agent", *cols, "monitor"], rows, notes([*cols, "monitor"]))


def _pin_cpu() -> None:
    """Set up a process of a run: pin it to the CPU ``swarm run`` chose for it
    (``time.pin_cpus``), every thread it has now (numpy's BLAS threads start at import)
    and, through inheritance, the ones it starts later (Zenoh's); and on SIGUSR1 write every
    thread's stack to its log (the launcher asks so of a process that did not end on SIGTERM,
    before it kills it)."""
    import faulthandler
    import signal

    from swarm.runs.launch import CPU_ENV

    faulthandler.register(signal.SIGUSR1, all_threads=True)

    cpu = os.environ.get(CPU_ENV)
    if cpu:
        for task in Path("/proc/self/task").iterdir():
            os.sched_setaffinity(int(task.name), {int(cpu)})


@click.group()
def cli() -> None:
    """c3swarm: one process per quadrotor, Zenoh between them, C3BF-QP safety filters."""


@cli.command()
@click.argument("config", type=click.Path(exists=False))
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]), help="override time.mode")
@click.option("--gui", is_flag=True, help="PyBullet GUI (needs a display)")
@click.option("--out", type=click.Path(path_type=Path), help="run folder (default runs/<name>-<time>)")
@click.option("--stop-on-agent-death", is_flag=True, help="stop the run when any agent process dies")
@click.option("--no-progress", is_flag=True)
@click.option("--run-id", help="Zenoh run id (default: <name>-<random>); keys live under swarm/<run-id>/")
@click.option(
    "--live",
    "live_port",
    type=int,
    is_flag=False,
    flag_value=8765,
    default=None,
    help="serve the scene live to Foxglove (ws://127.0.0.1:PORT, default 8765) while the run goes",
)
@_SECRETS
def run(
    config: str,
    mode: str | None,
    gui: bool,
    out: Path | None,
    stop_on_agent_death: bool,
    no_progress: bool,
    run_id: str | None,
    live_port: int | None,
    secrets: Path | None,
) -> None:
    """Run a scenario: world, one process per agent, recorder."""
    cfg = _load_or_exit(config, _overrides(mode))
    out = out or Path("runs") / f"{cfg.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    if cfg.script.enabled:  # the drones wait for a script (swarm.script, docs/scripting.md)
        click.echo(f"waiting for a script: Swarm.connect({str(out)!r}) in Python (docs/scripting.md)")
    code, metrics = run_scenario(
        cfg,
        out,
        gui=gui,
        progress=not no_progress,
        stop_on_agent_death=stop_on_agent_death,
        run_id=run_id,
        secrets=secrets,
        live_port=live_port,
    )
    if metrics.get("agents"):
        print_summary(metrics)
    click.echo(f"run folder: {out}")
    sys.exit(code)


def _process_args(config: str, run_id: str | None, port: int | None, mode: str | None) -> tuple[ScenarioConfig, str]:
    cfg = _load_or_exit(config, _overrides(mode, port))
    return cfg, run_id or cfg.name


def _zenoh_config(cfg: ScenarioConfig, run: str, role: Any, secrets: Path | None, agent_id: str | None = None) -> Any:
    """The process's Zenoh config with the run's credentials; exit 2 when access control
    is on and they are missing or unreadable."""
    from swarm.net import transport as tp
    from swarm.net.access import SecretsError

    if not cfg.network.access_control:
        return tp.process_config(cfg, role)
    if secrets is None:
        click.echo(
            "config error: network.access_control is on: pass --secrets DIR (the run's credentials, "
            "written by swarm run or swarm secrets)",
            err=True,
        )
        sys.exit(2)
    try:
        return tp.process_config(cfg, role, tp.Access.of(cfg, run, role, secrets, agent_id))
    except SecretsError as exc:
        click.echo(f"config error: {exc}", err=True)
        sys.exit(2)


@cli.command()
@click.argument("config")
@click.option("--run", "run_id", help="run id shared by all processes (default: the scenario name)")
@click.option(
    "--port", type=int, help="the world's listening port (in a star the recorder and launcher listen on the next two)"
)
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]))
@click.option("--gui", is_flag=True)
@click.option("--expect", multiple=True, help="other processes to wait for, e.g. recorder")
@_SECRETS
def world(
    config: str,
    run_id: str | None,
    port: int | None,
    mode: str | None,
    gui: bool,
    expect: tuple[str, ...],
    secrets: Path | None,
) -> None:
    """Start the world process alone (runs spread over machines)."""
    _pin_cpu()
    from swarm.net import transport as tp
    from swarm.world.main import main as world_main

    cfg, run_name = _process_args(config, run_id, port, mode)
    name_process("world", run_name)
    conf = _zenoh_config(cfg, run_name, tp.Role.WORLD, secrets)
    tp.exit_when_sent(world_main(cfg, run_name, conf, gui=gui, expect=expect), "world")


@cli.command()
@click.argument("config")
@click.option("--run", "run_id", help="run id shared by all processes (default: the scenario name)")
@click.option("--port", type=int, help="the port to listen on (network.port)")
@_SECRETS
def router(config: str, run_id: str | None, port: int | None, secrets: Path | None) -> None:
    """Start the run's Zenoh router (network.topology: router) or a star's bundle relay alone."""
    _pin_cpu()
    from swarm.net import transport as tp
    from swarm.runs.router import main as router_main

    cfg, run_name = _process_args(config, run_id, port, None)
    name_process("router", run_name)
    if cfg.topology != "router" and not cfg.uses_bundles:
        click.echo(
            f"config error: {config}: network.topology is {cfg.topology}, not router, and no agent takes bundles",
            err=True,
        )
        sys.exit(2)
    conf = _zenoh_config(cfg, run_name, tp.Role.ROUTER, secrets)
    tp.exit_when_sent(router_main(run_name, conf, cfg), "router")


@cli.command()
@click.argument("config")
@click.option("--id", "agent_id", required=True)
@click.option("--run", "run_id")
@click.option("--port", type=int)
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]))
@_SECRETS
def agent(
    config: str, agent_id: str, run_id: str | None, port: int | None, mode: str | None, secrets: Path | None
) -> None:
    """Start one agent process alone."""
    _pin_cpu()
    from swarm.agents.agent import main as agent_main
    from swarm.net import transport as tp

    cfg, run_name = _process_args(config, run_id, port, mode)
    name_process("agent", run_name, agent_id)
    try:
        cfg.agent(agent_id)
    except ConfigError as exc:
        click.echo(f"config error: {exc}", err=True)
        sys.exit(2)
    conf = _zenoh_config(cfg, run_name, tp.Role.AGENT, secrets, agent_id)
    tp.exit_when_sent(agent_main(cfg, agent_id, run_name, conf), f"agent {agent_id}")


@cli.command()
@click.argument("config")
@click.option("--out", required=True, type=click.Path(path_type=Path))
@click.option("--run", "run_id")
@click.option("--port", type=int)
@click.option("--live", "live_port", type=int, help="also serve the channels to Foxglove on ws://127.0.0.1:PORT")
@_SECRETS
def record(
    config: str, out: Path, run_id: str | None, port: int | None, live_port: int | None, secrets: Path | None
) -> None:
    """Start the recorder alone."""
    _pin_cpu()
    from swarm.ledger import Ledger
    from swarm.net import transport as tp
    from swarm.runs.record import main as record_main

    cfg, run_name = _process_args(config, run_id, port, None)
    name_process("recorder", run_name)
    out.mkdir(parents=True, exist_ok=True)
    target = out / "config.yaml"
    if not (target.exists() and target.resolve() == Path(config).resolve()):
        target.write_text(dump(cfg))
    real = any(a.backend == "crazyflie" for a in cfg.agents)
    linger_s = cfg.time.land_timeout_s + 1.0 if real else 0.0  # the world relays landings that long
    conf = _zenoh_config(cfg, run_name, tp.Role.RECORDER, secrets)
    ids, ledger = tuple(a.id for a in cfg.agents), Ledger.of(cfg)
    tp.exit_when_sent(record_main(run_name, out, conf, linger_s, live_port, ids, ledger), "recorder")


@cli.command("ros2-bridge")
@click.argument("config")
@click.option("--run", "run_id")
@click.option("--port", type=int, help="the run's router port (network.port)")
@_SECRETS
def ros2_bridge(config: str, run_id: str | None, port: int | None, secrets: Path | None) -> None:
    """Start the run's ROS 2 bridge alone (ros2.enabled; docs/ros2.md)."""
    _pin_cpu()
    from swarm.net import transport as tp
    from swarm.ros2.bridge import main as bridge_main

    cfg, run_name = _process_args(config, run_id, port, None)
    name_process("ros2-bridge", run_name)
    if not cfg.ros2.enabled:
        click.echo(f"config error: {config}: ros2.enabled is false", err=True)
        sys.exit(2)
    conf = _zenoh_config(cfg, run_name, tp.Role.ROS2, secrets)
    os._exit(bridge_main(cfg, run_name, conf))


@cli.command("ros2-bag")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), help="default RUN_DIR/ros2_bag")
def ros2_bag(run_dir: Path, out: Path | None) -> None:
    """Write a run as a ROS 2 bag (MCAP, ros2msg/cdr) that ros2 bag, Foxglove and rosbags open."""
    from swarm.runs.bag import write_bag

    try:
        path, n = write_bag(run_dir, out)
    except ConfigError as exc:
        click.echo(f"config error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"{path}: {n} messages")


@cli.command()
@click.argument("config")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path))
def secrets(config: str, out: Path) -> None:
    """Write credentials (and, with network.tls on and no files given, a certificate
    authority and certificate) for runs of CONFIG into OUT, to hand to processes started
    by hand on several machines with --secrets OUT. Copy OUT only to machines you trust."""
    from swarm.runs.launch import ensure_secrets

    cfg = _load_or_exit(config, {})
    ensure_secrets(cfg, out)
    click.echo(f"credentials: {out}")
    if cfg.ros2.enabled and cfg.network.port:  # what a ROS 2 participant sources (docs/ros2.md)
        from swarm.ros2.participant import write_env

        click.echo(f"ROS 2 participants: source {write_env(cfg, out, out)}")


@cli.command()
@click.argument("run_dir", type=click.Path(exists=True, path_type=Path))
def metrics(run_dir: Path) -> None:
    """Recompute metrics.json of a run folder from its run.mcap."""
    from swarm.runs.runfiles import write_metrics

    click.echo(json.dumps(write_metrics(run_dir), indent=2))


@cli.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--port", type=int, default=9090, show_default=True, help="the web viewer's HTTP port (127.0.0.1)")
@click.option("--no-browser", is_flag=True, help="serve only; open the printed address yourself")
def view(run_dir: Path, port: int, no_browser: bool) -> None:
    """The run in 3-D in a web browser, offline (Rerun's web viewer; RUN_DIR/view.rrd)."""
    from swarm.runs.view import main as view_main

    if not (run_dir / "run.mcap").exists():
        click.echo(f"error: {run_dir}: no run.mcap", err=True)
        sys.exit(2)
    sys.exit(view_main(run_dir, port, browser=not no_browser))


@cli.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
def report(run_dir: Path) -> None:
    """Plots (PNG) and a markdown summary of a run folder, in RUN_DIR/report/."""
    from swarm.runs.report import make_report

    out = make_report(run_dir)
    click.echo(f"report: {out / 'summary.md'}")


@cli.command()
@click.argument("config")
@click.option(
    "--filters",
    default="c3bf,hocbf",
    help="comma-separated: c3bf, hocbf, an installed plugin's name (docs/plugins.md), none (unfiltered)",
)
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]))
@click.option(
    "--realism",
    help="comma-separated world.realism presets to fly side by side (e.g. ideal,crazyflie_lab; default: the config's)",
)
@click.option(
    "--seeds",
    type=click.IntRange(min=1, max=100),
    default=1,
    show_default=True,
    help="fly each filter with this many seeds (config seed, +1, ...): each cell the mean [min, max]",
)
@click.option("--out", type=click.Path(path_type=Path), help="output folder (default runs/compare-<name>-<time>)")
def compare(config: str, filters: str, mode: str | None, realism: str | None, seeds: int, out: Path | None) -> None:
    """Run one scenario under each filter (in each world) and print the comparison table."""
    from swarm.plugins import UNFILTERED
    from swarm.plugins import names as filter_names
    from swarm.realism.settings import PRESETS
    from swarm.runs.compare import cells, in_world, with_filter
    from swarm.runs.compare import compare as run_compare
    from swarm.runs.readable import print_table

    names = [f.strip() for f in filters.split(",") if f.strip()]
    known = [*filter_names(), UNFILTERED]
    bad = [f for f in names if f not in known]
    if bad or not names:
        click.echo(f"--filters: unknown filter(s) {bad}; choose from {', '.join(known)}", err=True)
        sys.exit(2)
    worlds = None if realism is None else [w.strip() for w in realism.split(",") if w.strip()]
    if worlds is not None and (not worlds or any(w not in PRESETS for w in worlds)):
        click.echo(f"--realism: {realism!r}: choose presets from {', '.join(sorted(PRESETS))}", err=True)
        sys.exit(2)
    cfg = _load_or_exit(config, _overrides(mode))
    for w in worlds or ():
        try:
            in_world(cfg, w)
        except ConfigError as exc:
            click.echo(f"config error: {exc}", err=True)
            sys.exit(2)
    for name in names:  # a plugin that cannot be imported, refuses its options or the agents' level
        try:
            with_filter(cfg, name)
        except ConfigError as exc:
            click.echo(f"config error: {exc}", err=True)
            sys.exit(2)
    out = out or Path("runs") / f"compare-{cfg.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    rows = run_compare(cfg, names, out, worlds, seeds)
    header, body, legend = cells(rows)
    print_table(f"{cfg.name}: filters compared", header, body, legend)
    click.echo(f"saved: {out / 'compare.md'}")


class _SweepProgress:
    """A sweep's progress: a rich bar of the runs done, failed and running, and a line per
    finished run (its outcome, or why it failed)."""

    def __init__(self, total: int, done: int) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(
            TextColumn("[bold]sweep"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[failed]} failed, {task.fields[running]} running"),
            TimeElapsedColumn(),
            console=_console(),
        )
        self.task = self.bar.add_task("sweep", total=total, completed=done, failed=0, running=0)
        self.total, self.finished, self.failed, self.running = total, done, 0, 0
        self.lock = threading.Lock()  # runs start and end on the pool's threads

    def __enter__(self) -> _SweepProgress:
        self.bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.stop()

    def started(self, head: dict[str, Any]) -> None:
        with self.lock:
            self.running += 1
            self.bar.update(self.task, running=self.running)

    def done(self, row: dict[str, Any]) -> None:
        from swarm.runs.readable import fig

        with self.lock:
            self.finished += 1
            self.failed += bool(row.get("error"))
            self.running = max(0, self.running - 1)
            self.bar.update(self.task, completed=self.finished, failed=self.failed, running=self.running)
            head = f"[{self.finished}/{self.total}, {self.failed} failed] {row['run']}"
            if row.get("error"):
                self.bar.console.print(f"{head}: failed: {row['error']}", markup=False, highlight=False, soft_wrap=True)
                return
            self.bar.console.print(
                f"{head}: success={row['success']} collisions={row['collisions']} "
                f"margin_violations={row['margin_violations']} deadlock={row['deadlock']} "
                f"mean_time_to_goal_s={fig(row['mean_time_to_goal_s'], 'mean_time_to_goal_s')}",
                markup=False,
                highlight=False,
                soft_wrap=True,
            )


@cli.command()
@click.argument("config")
@click.option(
    "--axis",
    "axes",
    multiple=True,
    metavar="NAME=v1,v2,...",
    help="a knob and its values (repeatable): filter (c3bf, hocbf, an installed plugin's name, none, orca), "
    "gamma, gamma_ho, rho, "
    "sensing_radius_m, horizon_s, buffer_mps, contact_s, tiebreak, seed, obstacle_speed, approach_angle_deg; "
    "for generated scenarios also agents, radius, perturb_m, density",
)
@click.option("--jobs", type=int, default=os.cpu_count() or 1, show_default=True, help="runs at a time (local)")
@click.option("--out", type=click.Path(path_type=Path), help="output folder (default runs/sweep-<name>-<time>)")
@click.option(
    "--engine",
    type=click.Choice(["local", "ray"]),
    default="local",
    show_default=True,
    help="local: a pool on this machine; ray: each run a Ray task (docs/cluster.md)",
)
@click.option("--address", help="--engine ray: the Ray cluster's address (default: a local cluster)")
@click.option("--resume", is_flag=True, help="fly only the points of --out that have no row yet")
def sweep(
    config: str, axes: tuple[str, ...], jobs: int, out: Path | None, engine: str, address: str | None, resume: bool
) -> None:
    """Run a grid of variants of CONFIG (a file, or circle, sphere or random for generated
    swaps); write results.csv and one plot per metric."""
    from swarm.runs import sweep as sw

    try:
        if config in sw.GENERATORS:
            base, name = sw.generator_base(config), config
        else:
            cfg = _load_or_exit(config, {"time": {"mode": "lockstep"}})
            base, name = cfg.model_dump(mode="json"), cfg.name
        grid_axes = sw.parse_axes(list(axes))
        total = len(sw.grid(grid_axes))
        if resume and out is None:
            raise ConfigError("--resume: name the sweep's folder with --out")
        out = out or Path("runs") / f"sweep-{name}-{time.strftime('%Y%m%d-%H%M%S')}"
        with _SweepProgress(total, sw.finished_rows(out) if resume else 0) as progress:
            sw.sweep(
                base,
                grid_axes,
                out,
                jobs=jobs,
                on_start=progress.started,
                on_done=progress.done,
                engine=engine,
                address=address,
                resume=resume,
            )
    except (ConfigError, InputError) as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"saved: {out / 'results.csv'} and plots in {out}")


@cli.command()
@click.argument("kind", type=click.Choice(["circle", "sphere", "random", "doorway", "corridor", "trap", "forest"]))
@click.option("--agents", "n", type=int, help="number of agents (corridor: per side; trap: 1) [default 6, corridor 4]")
@click.option("--radius", type=float, help="circle or sphere radius [m] (default grows with N, 2 m at least)")
@click.option("--density", type=float, help="random sets: agents per m^2 [0.5]; forest: pillars per m^2 [0.3]")
@click.option("--gap", type=float, help="doorway: its width [m] [0.8]; corridor: its width [m] [0.5]")
@click.option(
    "--perturb",
    type=float,
    default=0.0,
    show_default=True,
    help="uniform random offset [m] of each start and goal (0: exact symmetry)",
)
@click.option("--rotate-deg", type=float, default=0.0, show_default=True, help="turn the pattern about z [deg]")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--speed", type=float, default=0.8, show_default=True, help="target speed [m/s]")
@click.option("--rho", type=float, default=1.0, show_default=True, help="responsibility share of each neighbour pair")
@click.option("--tiebreak", type=click.Choice(["none", "right_hand"]), default="right_hand", show_default=True)
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]), default="lockstep", show_default=True)
@click.option(
    "--realism",
    type=click.Choice(["crazyflie_lab", "ideal"]),
    default="crazyflie_lab",
    show_default=True,
    help="world.realism: a Crazyflie lab (downwash, drag, motors, wind, motion capture, links), or the perfect world",
)
@click.option(
    "--neighbours",
    type=click.Choice(["agents", "world"]),
    default="agents",
    show_default=True,
    help="neighbours.source: the agents' own states, or the world's roster of every drone (ground truth: ideal only)",
)
@click.option(
    "--room",
    default="8,8,3",
    show_default=True,
    metavar="X,Y,Z",
    help="the lab's flight volume [m], centred on the origin, floor at z = 0: starts and goals stay 0.3 m inside "
    "(a sphere too tall is squeezed into it)",
)
@click.option("--out", "-o", type=click.Path(path_type=Path), help="file to write (default: print)")
def scenario(kind: str, n: int | None, out: Path | None, room: str, **options: Any) -> None:
    """Write a generated scenario: a swap (antipodal points of a circle or a sphere, or
    random sets) or a scene among walls (N abreast through a doorway, two flows through a
    corridor, a drone in a U-shaped trap, a crossing of a forest of pillars)."""
    import math

    import yaml

    from swarm.config import resolve
    from swarm.offline.scenario import Room, SwapSettings, fit_room, generate

    o = options
    settings = SwapSettings(
        speed_mps=o["speed"], perturb_m=o["perturb"], rotation_rad=math.radians(o["rotate_deg"]), seed=o["seed"],
        mode=o["mode"], realism=o["realism"], neighbours=o["neighbours"],
    )  # fmt: skip
    if kind not in ("trap",) and n is None:
        n = 4 if kind == "corridor" else 6 if kind in ("doorway", "forest") else None
        if n is None:
            click.echo(f"error: swarm scenario {kind}: give --agents", err=True)
            sys.exit(2)
    try:
        size = tuple(float(v) for v in room.split(","))
        if len(size) != 3 or not all(math.isfinite(v) and v > 0 for v in size):
            raise ValueError(f"--room {room}: give three positive sizes in metres, X,Y,Z (e.g. 8,8,3)")
        raw = generate(kind, n or 1, settings, radius_m=o["radius"], density=o["density"], gap_m=o["gap"])
        raw = fit_room(raw, Room(size_m=(size[0], size[1], size[2])))
        raw["defaults"]["filter"]["rho"] = o["rho"]
        raw["defaults"]["tiebreak"] = {"kind": o["tiebreak"]}
        resolve(raw, f"generated {kind} scenario")  # validated before it is written
    except (ConfigError, ValueError) as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    header = (
        f"# Generated by: swarm scenario {kind} --agents {n or 1} --room {room} (units: m, m/s, s, Hz)\n"
        f"# Inside a {room.replace(',', ' x ')} m room centred on the origin, floor at z = 0\n"
    )
    text = header + yaml.safe_dump(raw, sort_keys=False, default_flow_style=None, width=120)
    if out:
        out.write_text(text)
        click.echo(f"wrote {out}")
    else:
        click.echo(text, nl=False)


@cli.group()
def cf() -> None:
    """Real Crazyflies through cflib: scan, status, recover, reboot (swarm.agents.cf_admin)."""


@cf.command("scan")
def cf_scan() -> None:
    """List the Crazyflies cflib finds (radios, USB, UDP stand-ins on 19850-19859)."""
    from swarm.agents.cf_admin import scan

    found = scan()
    click.echo("\n".join(found) if found else "no Crazyflie found")


def _cf_call(what: Callable[[], object]) -> object:
    try:
        return what()
    except (OSError, ValueError) as exc:  # (TimeoutError is an OSError)
        click.echo(f"swarm cf: {exc}", err=True)
        sys.exit(2)


@cf.command("status")
@click.argument("uri")
@click.option("--timeout-s", type=click.FloatRange(min=0.1, max=60.0), default=3.0, show_default=True,
              help="How long to wait for each answer (longer for a slow link or a busy simulated drone).")  # fmt: skip
def cf_status(uri: str, timeout_s: float) -> None:
    """The supervisor's state bits of the drone at URI."""
    from swarm.agents.cf_admin import status

    click.echo(", ".join(_cf_call(lambda: status(uri, timeout_s))) or "(no state bit set)")  # type: ignore[arg-type]


@cf.command("recover")
@click.argument("uri")
def cf_recover(uri: str) -> None:
    """Recover a crashed (tumbled) drone that is upright again; prints its states after."""
    from swarm.agents.cf_admin import recover

    click.echo(", ".join(_cf_call(lambda: recover(uri))) or "(no state bit set)")  # type: ignore[arg-type]


@cf.command("check")
@click.argument("uri")
@click.option(
    "--firmware", default="2026.04", show_default=True, help="the firmware on the drone (its thrust map), or crazysim"
)
@click.option("--pwm-per-newton", type=float, default=None, help="a calibration of your own instead")
def cf_check(uri: str, firmware: str, pwm_per_newton: float | None) -> None:
    """PROPELLERS OFF: send a known setpoint sequence and compare what the firmware decoded
    (its ctrltarget and stabilizer.thrust logs) with what its rules say it must: signs and
    thrust on your drone."""
    from swarm.agents.cf_admin import check
    from swarm.config import ThrustCalibration

    try:
        cal = ThrustCalibration(firmware=firmware, pwm_per_newton=pwm_per_newton)
    except ValueError as exc:
        click.echo(f"swarm cf check: {exc}", err=True)
        sys.exit(2)
    rows = _cf_call(lambda: check(uri, cal))
    bad = 0
    missing = rows[0]["missing"] if rows else []  # type: ignore[index]
    if missing:
        click.echo(f"the firmware logs no {', '.join(missing)}: those cannot be checked")
    for r in rows:  # type: ignore[attr-defined]
        fw = ", ".join(f"{k} {v:.3g}" for k, v in r["firmware"].items()) or "(nothing logged)"
        want = ", ".join(f"{k} {v:.3g}" for k, v in r["expected"].items())
        click.echo(f"{'ok  ' if r['ok'] else 'FAIL'} {r['step']}: firmware holds {fw}; its rules say {want}")
        bad += not r["ok"]
    sys.exit(1 if bad else 0)


@cf.command("reboot")
@click.argument("uri")
def cf_reboot(uri: str) -> None:
    """Power-cycle the drone (a locked one needs this) through its Crazyradio."""
    from swarm.agents.cf_admin import reboot

    _cf_call(lambda: reboot(uri))
    click.echo(f"{uri}: rebooted")


@cli.command()
def plugins() -> None:
    """List the safety filters (filter.kind), reference controllers (controller.kind) and planners
    (planner.kind) a config can name (entry-point groups c3swarm.filters, c3swarm.controllers,
    c3swarm.planners), each checked as a config would check it: imported, its levels and its
    options (docs/plugins.md)."""
    from swarm.plugins import CONTROLLERS, FILTERS, PLANNERS, PluginError, plugin_class, registered
    from swarm.safety.external import levels_of, options_of

    bad = 0
    for group, title in ((FILTERS, "safety filters"), (CONTROLLERS, "reference controllers"), (PLANNERS, "planners")):
        try:
            eps = registered(group)
        except PluginError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)
        click.echo(f"{title} ({group}):")
        for name in sorted(eps):
            ep = eps[name]
            dist = getattr(ep.dist, "name", None) or "c3swarm"
            try:
                cls = plugin_class(group, name)
            except PluginError as exc:
                click.echo(f"  {name}  ({dist}: {ep.value})\n    error: {exc}")
                bad += 1
                continue
            opts = options_of(cls)
            fields = ", ".join(f"{k}={f.default!r}" for k, f in opts.model_fields.items()) if opts else "none"
            levels = f"\n    levels: {', '.join(lv.value for lv in levels_of(cls))}" if group == FILTERS else ""
            click.echo(f"  {name}  ({dist}: {ep.value}){levels}\n    options: {fields}")
    sys.exit(1 if bad else 0)


def main() -> None:
    cli()


if __name__ == "__main__":
    main()
