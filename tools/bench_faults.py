"""Fault benchmark: one real run per fault, injected at t = 2 s of a swarm on a collision
course (a 2-drone swap with a third drone crossing it). Prints one JSON line per case:
how long the fault took to be seen, and what the run did.

    python -m tools.bench_faults                  # every case (about 2 min on 2 cores)
    python -m tools.bench_faults --case recorder_kill --mode realtime

Keys (stable): case, mode, detected_ms (fault to the first sign the system saw it: the
world's log line, the launcher's stop; null where nothing is to be seen), outcome (one
line), stop_reason, complete, collisions (contacts), margin_violations (pairs and agent-obstacles
inside the safety radius), dead_agent_contacts, stalls, lost_agents,
reached (agents at their goal), sent (forgeries sent; null for other cases) and
victim_unaffected (forgeries: lockstep, the victim's path is the one of a run without the
attack to the bit; realtime, it reached its goal without contact).

Cases: agent_kill, agent_stop (SIGSTOP for 3 s, then SIGCONT), recorder_kill, world_kill,
world_stop (1 s), recorder_stop (3 s, while the run ends: the recording against what each
process says it sent), forged_command (another agent's credentials, the victim's next tick),
outsider (no credentials), bad_config (the slowest refusal over the malformed configs of
the tests), and a run's own agent gone wrong in place of cf3, hovering between cf1 and cf2
(``tools/rogue.py``, from t = 1 s): rogue_flood (a thousand states per tick),
rogue_nan, rogue_far (a kilometre away), rogue_fast (300 m/s), rogue_reorder (each tick
again, and one 50 ticks old), rogue_mute (never a command). Keys of those rows also:
``dropped`` (its messages the receivers dropped), ``offenders`` (whom the metrics name).
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from swarm.config import ScenarioConfig, load
from swarm.net import transport as tp
from swarm.net.messages import CommandBody, decode, encode
from swarm.runs.launch import RunHandle

ROOT = Path(__file__).resolve().parents[1]
FAULT_AT_S = 2.0
AGENTS = [
    {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
    {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
    {"id": "cf3", "start": [2.0, 2.0, 1.0], "goal": [2.0, -2.0, 1.0], "speed_mps": 0.5},
]
ZERO = CommandBody.zero().fields()  # motors off, a clean tick


def _config(mode: str, **over: Any) -> ScenarioConfig:
    base = {"name": "faults", "duration_s": 10.0, "agents": AGENTS, "time": {"mode": mode, "late_command": "brake"}}
    return load(ROOT / "configs" / "swap_2.yaml", {**base, **over})


def _log_time(path: Path, pattern: str, since: float, timeout_s: float = 10.0) -> float | None:
    """Wall time [s] when ``pattern`` first appears in ``path`` (polled every 5 ms)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and re.search(pattern, path.read_text(errors="replace")):
            return time.time() - since
        time.sleep(0.005)
    return None


def _summary(
    case: str, cfg: ScenarioConfig, h: RunHandle, detected_s: float | None, outcome: str, **extra: Any
) -> dict[str, Any]:
    m = h.result
    return {
        "case": case,
        "mode": cfg.time.mode.value,
        "detected_ms": None if detected_s is None else round(detected_s * 1e3, 1),
        "outcome": outcome,
        "stop_reason": m.get("stop_reason"),
        "complete": m.get("complete"),
        "collisions": m.get("collisions"),
        "margin_violations": m.get("margin_violations"),
        "dead_agent_contacts": m.get("dead_agent_contacts"),
        "stalls": m.get("stalls"),
        "lost_agents": m.get("lost_agents"),
        "reached": sorted(a for a, v in m.get("agents", {}).items() if v["reached_goal"]),
        "sent": None,
        "victim_unaffected": None,
        **extra,
    }


def _faulted(out: Path, mode: str, name: str, sig: signal.Signals) -> tuple[ScenarioConfig, RunHandle, float]:
    """Start the run, send ``sig`` to process ``name`` at the fault time; (config, run, wall time
    of the signal [s, time.time])."""
    cfg = _config(mode)
    h = RunHandle.start(cfg, out)
    h.wait_sim_time(FAULT_AT_S)
    t0 = time.time()
    h.kill(name, sig)
    return cfg, h, t0


def agent_kill(out: Path, mode: str) -> dict[str, Any]:
    cfg, h, t0 = _faulted(out, mode, "agent-cf3", signal.SIGKILL)
    seen = _log_time(h.out / "logs" / "world.log", r"agent cf3 gone", t0)
    h.wait()
    return _summary("agent_kill", cfg, h, seen, "the world lands cf3's drone; cf1 and cf2 fly on")


def agent_stop(out: Path, mode: str) -> dict[str, Any]:
    cfg, h, t0 = _faulted(out, mode, "agent-cf3", signal.SIGSTOP)
    lockstep = mode == "lockstep"  # (realtime has no stall to report: the drone brakes)
    seen = _log_time(h.out / "logs" / "world.log", r"has waited [0-9.]+ s for \['cf3'\]", t0, 3.0) if lockstep else None
    time.sleep(max(0.0, 3.0 - (time.time() - t0)))  # the fault: 3 s stopped
    h.kill("agent-cf3", signal.SIGCONT)
    h.wait()
    what = "the world waits, logs the stall, and goes on" if lockstep else "cf3's drone brakes"
    return _summary("agent_stop", cfg, h, seen, what)


def _kill_and_time(out: Path, mode: str, name: str) -> tuple[ScenarioConfig, RunHandle, float]:
    """SIGKILL ``name`` at the fault time; (config, run, seconds until the launcher stopped the run)."""
    cfg, h, t0 = _faulted(out, mode, name, signal.SIGKILL)
    while (reason := h.poll(wait_s=0.002)) is None:
        pass
    seen = time.time() - t0
    h.finish(reason)
    return cfg, h, seen


def recorder_kill(out: Path, mode: str) -> dict[str, Any]:
    cfg, h, seen = _kill_and_time(out, mode, "recorder")
    rec = h.result.get("recording", {})
    until = rec.get("recorded_until_s")
    what = f"run stopped; metrics from the cut file, up to t = {until:.2f} s" if until is not None else "run stopped"
    return _summary("recorder_kill", cfg, h, seen, what, recorded_until_s=until)


def world_kill(out: Path, mode: str) -> dict[str, Any]:
    cfg, h, seen = _kill_and_time(out, mode, "world")
    return _summary("world_kill", cfg, h, seen, "run stopped with the cause in one line")


def world_stop(out: Path, mode: str) -> dict[str, Any]:
    cfg, h, _t0 = _faulted(out, mode, "world", signal.SIGSTOP)
    time.sleep(1.0)  # the fault: the world frozen for 1 s
    h.kill("world", signal.SIGCONT)
    h.wait()
    return _summary("world_stop", cfg, h, None, "the world resumes; agents wait for its next tick")


def recorder_stop(out: Path, mode: str) -> dict[str, Any]:
    cfg, h, _t0 = _faulted(out, mode, "recorder", signal.SIGSTOP)
    time.sleep(3.0)  # the fault: the recorder frozen for 3 s, while the run ends
    h.kill("recorder", signal.SIGCONT)
    h.wait()
    m = h.result
    gaps = m.get("recording_gaps") or []
    what = f"the recording holds {m['recording']['summary']}; " + (
        f"{m['lost_messages']} lost, in gaps {gaps}" if gaps else "nothing lost"
    )
    return _summary("recorder_stop", cfg, h, None, what, lost_messages=m.get("lost_messages"))


ROGUE_AGENTS = [
    {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
    {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
    {"id": "cf3", "start": [2.0, 0.0, 1.0], "goal": [2.0, 0.0, 1.0]},  # the rogue: it hovers between them
]


def _rogue(out: Path, mode: str, fault: str) -> dict[str, Any]:
    """cf3's process replaced by a rogue of the run (``tools/rogue.py``)."""

    cfg = _config(mode, agents=ROGUE_AGENTS, time={"mode": mode, "late_command": "brake", "lockstep_timeout_s": 1.0})
    h = RunHandle.start(cfg, out, stand_ins={"cf3": ("tools.rogue", ["--mode", fault])})
    h.wait()
    m = h.result
    o = m.get("offenders", {}).get("cf3", {})
    by = ", ".join(o.get("dropped_by", [])) or "no one"
    what = f"{o.get('dropped', 0)} of its states dropped by {by} ({', '.join(sorted(o.get('reasons', {})))})"
    if fault == "mute":
        quiet = o.get("longest_silence_s", 0.0)
        what = f"never a command: waited for once, then {m.get('late_ticks')} late ticks; silent {quiet:.1f} s"
    named = sorted(m.get("offenders", {}))
    what += f"; named: {', '.join(named) or 'no one'}"
    return _summary(f"rogue_{fault}", cfg, h, None, what, dropped=o.get("dropped"), offenders=named)


def rogue_flood(out: Path, mode: str) -> dict[str, Any]:
    return _rogue(out, mode, "flood")


def rogue_nan(out: Path, mode: str) -> dict[str, Any]:
    return _rogue(out, mode, "nan")


def rogue_far(out: Path, mode: str) -> dict[str, Any]:
    return _rogue(out, mode, "far")


def rogue_fast(out: Path, mode: str) -> dict[str, Any]:
    return _rogue(out, mode, "fast")


def rogue_reorder(out: Path, mode: str) -> dict[str, Any]:
    return _rogue(out, mode, "reorder")


def rogue_mute(out: Path, mode: str) -> dict[str, Any]:
    return _rogue(out, mode, "mute")


def _attacker_session(cfg: ScenarioConfig, acc: tp.Access | None) -> tuple[zenoh.Session, str]:
    """The attacker's session and how it opened. Through a router a client without the run's
    credentials has its one link refused and does not open (tests/integration/test_forged.py):
    it then tries as a peer, which opens alone."""
    try:
        return tp.open_session(tp.process_config(cfg, tp.Role.OBSERVER, acc)), ""
    except zenoh.ZError:
        peer = cfg.model_copy(update={"network": cfg.network.model_copy(update={"topology": "mesh"})})
        refused = "the router refused its link; as a peer, "
        return tp.open_session(tp.process_config(peer, tp.Role.OBSERVER, acc)), refused


def _attack(out: Path, mode: str, case: str, credentials_of: str | None) -> dict[str, Any]:
    cfg = _config(mode)
    h = RunHandle.start(cfg, out)
    acc = h.access(tp.Role.AGENT, credentials_of) if credentials_of else None
    session, opened = _attacker_session(h.cfg, acc)
    clock = tp.open_channel(session, tp.Keys(h.run).clock)
    pub = session.declare_publisher(tp.Keys(h.run).command("cf1"))
    sent, heard = 0, 0
    dt = 1.0 / cfg.time.control_hz
    stop = threading.Event()

    def attack() -> None:
        nonlocal sent, heard
        while not stop.is_set():
            s = tp.wait_sample(clock, time.monotonic() + 0.05)
            k = decode(tp.payload(s), h.run, ("clock",), ("done",)).k if s is not None else int(h.progress.t_s / dt)
            heard += s is not None
            pub.put(encode("command", h.run, "cf1", 10**6 + k, (k + 1) * dt, k + 1, dropped=0, **ZERO))
            sent += 1

    th = threading.Thread(target=attack, daemon=True)
    th.start()
    h.wait()
    stop.set()
    th.join(5.0)
    linked = len(list(session.info.peers_zid()))
    session.close()
    res = _summary(
        case,
        cfg,
        h,
        None,
        f"{opened}zero-thrust commands for cf1's next tick; heard {heard} clocks; linked to {linked} processes",
    )
    res["sent"] = sent
    victim = h.result["agents"]["cf1"]
    if mode == "lockstep":
        clean = RunHandle.start(cfg, out.with_name(out.name + "-clean"))
        clean.wait()
        ref = clean.result["agents"]["cf1"]
        same = ("path_length_m", "min_h", "time_to_goal_s", "max_path_deviation_m")  # not the solve times
        res["victim_unaffected"] = all(victim[k] == ref[k] for k in same)
    else:
        res["victim_unaffected"] = bool(victim["reached_goal"] and h.result["collisions"] == 0)
    return res


def forged_command(out: Path, mode: str) -> dict[str, Any]:
    return _attack(out, mode, "forged_command", "cf2")


def outsider(out: Path, mode: str) -> dict[str, Any]:
    return _attack(out, mode, "outsider", None)


def bad_config(out: Path, mode: str) -> dict[str, Any]:
    from tools.bad_configs import write_bad_files  # the malformed configs the tests refuse

    out.mkdir(parents=True, exist_ok=True)
    slowest, codes = 0.0, set()
    for _case, (path, _needle) in write_bad_files(out).items():
        t0 = time.monotonic()
        p = subprocess.run(
            [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(out / "never")],
            capture_output=True,
            timeout=60,
            cwd=ROOT,
        )
        slowest = max(slowest, time.monotonic() - t0)
        codes.add(p.returncode)
    return {
        "case": "bad_config",
        "mode": mode,
        "detected_ms": round(slowest * 1e3, 1),
        "outcome": f"every one refused with exit {sorted(codes)}, nothing started",
        "stop_reason": None,
        "complete": None,
        "collisions": None,
        "margin_violations": None,
        "dead_agent_contacts": None,
        "stalls": None,
        "lost_agents": None,
        "reached": None,
        "sent": None,
        "victim_unaffected": None,
    }


CASES: dict[str, Callable[[Path, str], dict[str, Any]]] = {
    f.__name__: f
    for f in (
        agent_kill,
        agent_stop,
        recorder_kill,
        world_kill,
        world_stop,
        recorder_stop,
        forged_command,
        outsider,
        bad_config,
        rogue_flood,
        rogue_nan,
        rogue_far,
        rogue_fast,
        rogue_reorder,
        rogue_mute,
    )
}


def main(cases: list[str], modes: list[str], out: Path) -> None:
    for case in cases:
        for mode in modes:
            print(json.dumps(CASES[case](out / f"{case}-{mode}", mode)), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", action="append", choices=sorted(CASES), help="default: every case")
    ap.add_argument("--mode", action="append", choices=["lockstep", "realtime"], help="default: both")
    ap.add_argument("--out", type=Path, default=None, help="run folders (default: a temporary folder)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        main(args.case or list(CASES), args.mode or ["lockstep", "realtime"], args.out or Path(tmp))


def table(rows: list[dict[str, Any]]) -> str:
    """The markdown table of a run of this benchmark (docs/benchmarks.md quotes it)."""
    out = [
        "| case | mode | detected [ms] | outcome | stop reason | complete | contacts / inside the safety radius "
        "| at their goal |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        reached = "-" if r["reached"] is None else (", ".join(r["reached"]) or "none")
        extra = ""
        if r.get("sent") is not None:
            extra = f"; {r['sent']} sent, victim unaffected: {'yes' if r['victim_unaffected'] else 'NO'}"
        cells = [
            r["case"],
            r["mode"],
            "-" if r["detected_ms"] is None else f"{r['detected_ms']:.0f}",
            r["outcome"] + extra,
            r["stop_reason"] or "-",
            "-" if r["complete"] is None else str(r["complete"]),
            "-" if r["collisions"] is None else f"{r['collisions']} / {r.get('margin_violations', '-')}",
            reached,
        ]
        out.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(out)
