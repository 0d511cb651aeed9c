"""The ``swarm`` command line (click): run, world, agent, record, metrics.

``swarm run`` validates the config before anything starts, writes the resolved config
into the run folder, starts the recorder, one process per agent and the world (each in
its own process group), shows progress from the world's status messages, and stops
everything when the scenario ends, on Ctrl-C, or when the world or the recorder dies.
An agent that dies is reported (``lost_agents``) while the others fly on, as DESIGN.md
section 7 asks; ``--stop-on-agent-death`` stops the whole run instead.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import click

from swarm.config import ConfigError, ScenarioConfig, dump, load


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


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class Supervisor:
    """Child processes, each in its own session (process group), logs to files."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        log_dir.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, args: list[str]) -> None:
        log = open(self.log_dir / f"{name}.log", "wb")  # noqa: SIM115 - owned by the child
        self.procs[name] = subprocess.Popen(
            [sys.executable, *args], stdout=log, stderr=subprocess.STDOUT, start_new_session=True
        )

    def exited(self) -> dict[str, int]:
        return {n: p.returncode for n, p in self.procs.items() if p.poll() is not None}

    def wait(self, names: list[str], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(self.procs[n].poll() is not None for n in names if n in self.procs):
                return True
            time.sleep(0.05)
        return False

    def stop_all(self, grace_s: float = 5.0) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                _signal_group(p, signal.SIGTERM)
        if not self.wait(list(self.procs), grace_s):
            for p in self.procs.values():
                if p.poll() is None:
                    _signal_group(p, signal.SIGKILL)
            self.wait(list(self.procs), 2.0)
        for p in self.procs.values():  # reap the groups' leftovers too
            _signal_group(p, signal.SIGKILL)


def _signal_group(p: subprocess.Popen[bytes], sig: int) -> None:
    try:
        os.killpg(p.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def run_scenario(
    cfg: ScenarioConfig,
    out: Path,
    *,
    gui: bool = False,
    progress: bool = True,
    stop_on_agent_death: bool = False,
    run_id: str | None = None,
    wall_limit_s: float | None = None,
) -> tuple[int, dict[str, Any]]:
    """Run a whole scenario as separate processes; returns (exit code, metrics)."""
    from swarm import transport as tp
    from swarm.messages import DecodeError, decode
    from tools.runfiles import write_metrics

    port = cfg.network.port or free_port(cfg.network.host)
    cfg = cfg.model_copy(update={"network": cfg.network.model_copy(update={"port": port})})
    run = run_id or f"{cfg.name}-{secrets.token_hex(3)}"
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.yaml"
    cfg_path.write_text(dump(cfg))
    sup = Supervisor(out / "logs")
    common = [str(cfg_path), "--run", run]
    sup.start("recorder", ["-m", "tools.record", *common, "--out", str(out)])
    for a in cfg.agents:
        sup.start(f"agent-{a.id}", ["-m", "agents.agent", *common, "--id", a.id])
    sup.start("world", ["-m", "world.main", *common, "--expect", "recorder", *(["--gui"] if gui else [])])

    interrupted = {"now": False}
    old = signal.signal(signal.SIGINT, lambda s, f: interrupted.__setitem__("now", True))
    session = tp.open_session(tp.process_config(cfg.network, is_world=False))
    status_sub = tp.open_channel(session, tp.Keys(run).status, 4096)
    state_sub = tp.open_channel(session, tp.Keys(run).all_states, 1 << 15)
    infeasible: dict[str, int] = {}
    last: dict[str, Any] = {}
    reason = "completed"
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.1f} s sim"),
        TextColumn("{task.fields[info]}"), TimeElapsedColumn(), disable=not progress, transient=False,
    )  # fmt: skip
    limit = wall_limit_s or (cfg.time.start_timeout_s + 20.0 * cfg.duration_s + 60.0)
    t0 = time.monotonic()
    try:
        with bar:
            task = bar.add_task(cfg.name, total=cfg.duration_s, info="starting")
            while True:
                for s in tp.drain(status_sub):
                    try:
                        m = decode(tp.payload(s), run, ("status",))
                    except DecodeError:
                        continue
                    last = {"t": m.t, **m.body}
                for s in tp.drain(state_sub):
                    try:
                        m = decode(tp.payload(s), run, ("state",))
                    except DecodeError:
                        continue
                    infeasible[m.src] = m["infeasible"]
                if last:
                    bar.update(
                        task, completed=min(last["t"], cfg.duration_s),
                        info=f"rtf {last['rtf']:.2f}  min sep {last['min_sep']:.3f} m  "
                        f"infeasible {sum(infeasible.values())}  collisions {last['collisions']}",
                    )  # fmt: skip
                ex = sup.exited()
                if "world" in ex:
                    reason = "completed" if ex["world"] == 0 else f"world exited with {ex['world']}"
                    break
                if "recorder" in ex:
                    reason = f"recorder exited with {ex['recorder']}"
                    break
                dead = [n for n in ex if n.startswith("agent-")]
                if dead and stop_on_agent_death:
                    reason = f"{dead[0]} died"
                    break
                if interrupted["now"]:
                    reason = "interrupted"
                    break
                if time.monotonic() - t0 > limit:
                    reason = "wall-clock limit"
                    break
                time.sleep(0.05)
        if reason == "completed":
            sup.wait(["recorder"], 15.0)
            sup.wait([n for n in sup.procs if n.startswith("agent-")], 5.0)
    finally:
        sup.stop_all()
        signal.signal(signal.SIGINT, old)
    metrics: dict[str, Any] = {}
    if (out / "run.mcap").exists():
        try:
            metrics = write_metrics(out)
        except Exception as exc:  # a run cut short may leave a partial file
            click.echo(f"could not compute metrics: {exc}", err=True)
    metrics_file = out / "metrics.json"
    if metrics:
        metrics["stop_reason"] = reason
        metrics["exit_codes"] = {n: p.returncode for n, p in sup.procs.items()}
        metrics_file.write_text(json.dumps(metrics, indent=2))
    code = 0 if reason == "completed" else 1
    return code, metrics


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
def run(
    config: str, mode: str | None, gui: bool, out: Path | None, stop_on_agent_death: bool, no_progress: bool
) -> None:
    """Run a scenario: world, one process per agent, recorder."""
    cfg = _load_or_exit(config, _overrides(mode))
    out = out or Path("runs") / f"{cfg.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    code, metrics = run_scenario(cfg, out, gui=gui, progress=not no_progress, stop_on_agent_death=stop_on_agent_death)
    if metrics:
        keys = ("collisions", "min_separation_m", "min_obstacle_clearance_m", "all_reached_goal", "duration_s",
                "real_time_factor", "late_ticks", "dropped_messages", "lost_agents", "stop_reason")  # fmt: skip
        for k in keys:
            click.echo(f"{k:>26}: {metrics.get(k)}")
        for aid, a in metrics["agents"].items():
            click.echo(
                f"{aid:>26}: reached={a['reached_goal']} t_goal={a['time_to_goal_s']} "
                f"path={a['path_length_m']:.2f} m min_h={a['min_h']} infeasible={a['infeasible_ticks']}"
            )
    click.echo(f"run folder: {out}")
    sys.exit(code)


def _process_args(config: str, run_id: str | None, port: int | None, mode: str | None) -> tuple[ScenarioConfig, str]:
    cfg = _load_or_exit(config, _overrides(mode, port))
    return cfg, run_id or cfg.name


@cli.command()
@click.argument("config")
@click.option("--run", "run_id", help="run id shared by all processes (default: the scenario name)")
@click.option("--port", type=int, help="the world's listening port")
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]))
@click.option("--gui", is_flag=True)
@click.option("--expect", multiple=True, help="other processes to wait for, e.g. recorder")
def world(
    config: str, run_id: str | None, port: int | None, mode: str | None, gui: bool, expect: tuple[str, ...]
) -> None:
    """Start the world process alone (runs spread over machines)."""
    from swarm import transport as tp
    from world.main import main as world_main

    cfg, run_name = _process_args(config, run_id, port, mode)
    os._exit(world_main(cfg, run_name, tp.process_config(cfg.network, is_world=True), gui=gui, expect=expect))


@cli.command()
@click.argument("config")
@click.option("--id", "agent_id", required=True)
@click.option("--run", "run_id")
@click.option("--port", type=int)
@click.option("--mode", type=click.Choice(["lockstep", "realtime"]))
def agent(config: str, agent_id: str, run_id: str | None, port: int | None, mode: str | None) -> None:
    """Start one agent process alone."""
    from agents.agent import main as agent_main
    from swarm import transport as tp

    cfg, run_name = _process_args(config, run_id, port, mode)
    try:
        cfg.agent(agent_id)
    except ConfigError as exc:
        click.echo(f"config error: {exc}", err=True)
        sys.exit(2)
    os._exit(agent_main(cfg, agent_id, run_name, tp.process_config(cfg.network, is_world=False)))


@cli.command()
@click.argument("config")
@click.option("--out", required=True, type=click.Path(path_type=Path))
@click.option("--run", "run_id")
@click.option("--port", type=int)
def record(config: str, out: Path, run_id: str | None, port: int | None) -> None:
    """Start the recorder alone."""
    from swarm import transport as tp
    from tools.record import main as record_main

    cfg, run_name = _process_args(config, run_id, port, None)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(dump(cfg))
    os._exit(record_main(run_name, out, tp.process_config(cfg.network, is_world=False)))


@cli.command()
@click.argument("run_dir", type=click.Path(exists=True, path_type=Path))
def metrics(run_dir: Path) -> None:
    """Recompute metrics.json of a run folder from its run.mcap."""
    from tools.runfiles import write_metrics

    click.echo(json.dumps(write_metrics(run_dir), indent=2))


def main() -> None:
    cli()


if __name__ == "__main__":
    main()
