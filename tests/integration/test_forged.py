"""Forged commands (issue 20's attack) against real runs.

* From the launcher's own session (allowed to publish anywhere in its run): a header naming
  another agent than its key, or a tick and time the world has not reached, with zero
  thrust. The world drops and counts both, and the victim flies on.
* From a session without the run's credentials: it cannot link to any process, so it
  neither hears the run nor reaches it.
* From a session with another agent's credentials (a compromised or buggy agent), a
  plausible command (the victim's id, the next tick, its time): Zenoh's access control at
  the run's router (or the world, in a mesh) refuses it, and the victim's flight is the same,
  to the bit, as a run without the attack (lockstep). With access control off, the same
  attack is flown and changes the victim's flight: the test can fail.
"""

from __future__ import annotations

import json
import re
import threading
import time

import pytest
import zenoh

from swarm.net import transport as tp
from swarm.net.cells import cell_of
from swarm.net.messages import CommandBody, decode, encode
from swarm.runs.launch import RunHandle

from .conftest import scenario, wait_linked

ZERO_THRUST = {**CommandBody.zero().fields(), "dropped": 0}  # motors off, a clean tick


def test_forged_commands_are_dropped_and_the_victim_flies_on(start_run):
    # a mesh: the world accepts the launcher's link, so its access control lets the launcher's
    # forgeries through to the world's own checks (in a star the world opens that link)
    h = start_run(scenario("swap_2.yaml", network={"topology": "mesh"}), "forged")
    h.wait_sim_time(1.0)
    evil = h.session.declare_publisher(f"swarm/{h.run}/agent/evil/command")
    own = h.session.declare_publisher(f"swarm/{h.run}/agent/cf1/command")
    for i in range(5):
        evil.put(encode("command", h.run, "cf1", 10**9 + i, 1.2, 120, **ZERO_THRUST))  # header cf1, key evil
        own.put(encode("command", h.run, "cf1", 10**9 + i, 1e9, 10**9, **ZERO_THRUST))  # a tick from the far future
    assert h.wait() == "completed"
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["all_reached_goal"], m
    assert m["agents"]["cf1"]["path_length_m"] > 3.5  # it flew its swap, never brought down
    log = (h.out / "logs" / "world.log").read_text()
    assert "sender is not its key's agent" in log or m["dropped_messages"] >= 10, log[-2000:]


class Attacker:
    """A session that answers every clock of the run with a zero-thrust command for
    ``victim`` on the victim's own key, for the next tick at its exact time: the most
    plausible forgery there is."""

    def __init__(self, h: RunHandle, conf, victim: str) -> None:
        self.h, self.victim = h, victim
        self.session = tp.open_session(conf)
        keys = tp.Keys(h.run)
        self.clock = tp.open_channel(self.session, keys.clock)
        self.pub = self.session.declare_publisher(keys.command(victim))
        self.heard = self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        dt = 1.0 / self.h.cfg.time.control_hz
        while not self._stop.is_set():
            s = tp.wait_sample(self.clock, time.monotonic() + 0.05)
            if s is None:
                continue
            self.heard += 1
            k = decode(tp.payload(s), self.h.run, ("clock",), ("done",)).k
            self.pub.put(encode("command", self.h.run, self.victim, 10**6 + k, (k + 1) * dt, k + 1, **ZERO_THRUST))
            self.sent += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.session.close()


def _attacked(start_run, name: str, access_control: bool, credentials_of: str | None) -> tuple[dict, Attacker]:
    cfg = scenario("swap_2.yaml", name=name, network={"access_control": access_control})
    h = start_run(cfg, name)
    acc = h.access(tp.Role.AGENT, credentials_of) if credentials_of else None
    attacker = Attacker(h, tp.process_config(h.cfg, tp.Role.OBSERVER, acc), "cf1")
    try:
        assert h.wait() == "completed"
    finally:
        attacker.stop()
    return json.loads((h.out / "metrics.json").read_text()), attacker


def test_another_agents_credentials_cannot_command_a_drone(start_run):
    clean = start_run(scenario("swap_2.yaml", name="clean"), "clean")
    assert clean.wait() == "completed"
    ref = json.loads((clean.out / "metrics.json").read_text())

    m, attacker = _attacked(start_run, "acl", True, "cf2")
    assert attacker.heard > 50 and attacker.sent > 50  # it is in the run: it hears the clock and publishes
    assert m["collisions"] == 0 and m["all_reached_goal"]
    for key in ("path_length_m", "min_h", "time_to_goal_s", "max_path_deviation_m"):
        assert m["agents"]["cf1"][key] == ref["agents"]["cf1"][key], key  # not one forged command was flown

    # the same attack without access control: the forged commands are flown (cf1 misses its goal or flies
    # another path)
    m, attacker = _attacked(start_run, "open", False, None)
    assert attacker.sent > 50
    assert (
        not m["agents"]["cf1"]["reached_goal"]
        or m["agents"]["cf1"]["path_length_m"] != ref["agents"]["cf1"]["path_length_m"]
    )


def _outsider(cfg, acc) -> zenoh.Session:
    """A session that the run's processes should refuse to link to. Through a router, a
    client's one link is refused, so it does not even open: then a peer instead, which
    opens alone."""
    conf = tp.process_config(cfg, tp.Role.OBSERVER, acc)
    if cfg.topology != "router":
        return tp.open_session(conf)
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        tp.open_session(conf)
    peer = cfg.model_copy(update={"network": cfg.network.model_copy(update={"topology": "mesh"})})
    return tp.open_session(tp.process_config(peer, tp.Role.OBSERVER, acc))


def test_a_session_without_the_runs_credentials_hears_and_reaches_nothing(start_run):
    # realtime: the run lasts while the outsiders try (a lockstep swap_2 is over in under a second)
    cfg = scenario("swap_2.yaml", name="outsider", time={"mode": "realtime", "late_command": "brake"})
    h = start_run(cfg, "outsider")
    h.wait_sim_time(0.5)
    wrong = tp.Access(h.run, "agent-cf2", h.out / "wrong", tuple(a.id for a in cfg.agents))
    (h.out / "wrong").mkdir(mode=0o700)
    (h.out / "wrong" / "users.txt").write_text("agent-cf2:not-the-password\n")
    (h.out / "wrong" / "users.txt").chmod(0o600)
    outsiders = []
    for acc in (None, wrong):  # no credentials at all; a wrong password
        s = _outsider(h.cfg, acc)
        sub = tp.open_channel(s, f"swarm/{h.run}/**")
        pub = s.declare_publisher(tp.Keys(h.run).command("cf1"))
        outsiders.append((s, sub, pub))
    puts = 0
    for _ in range(20):  # on each of 20 world status messages (about 2 s of the run)
        h.wait_sim_time(h.progress.t_s + 0.02)
        for _s, _sub, pub in outsiders:
            pub.put(encode("command", h.run, "cf1", 1, h.progress.t_s, int(h.progress.t_s * 100), **ZERO_THRUST))
        puts += 1
    assert h.wait() == "completed"
    own = tp.Keys(h.run).command("cf1")
    for s, sub, _pub in outsiders:
        assert list(s.info.peers_zid()) == []  # no process of the run let it link
        heard = [str(x.key_expr) for x in tp.drain(sub)]
        assert heard == [own] * puts  # its own puts (a session hears itself), nothing of the run
        s.close()
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["all_reached_goal"] and m["collisions"] == 0


def test_over_tls_only_sessions_with_the_runs_certificates_link(start_run, tmp_path):
    from swarm.net import access

    cfg = scenario(
        "swap_2.yaml",
        name="tls",
        network={"tls": {"enabled": True}},
        time={"mode": "realtime", "late_command": "brake"},
    )
    h = start_run(cfg, "tls")
    h.wait_sim_time(0.5)
    assert h.secrets is not None and (h.secrets / "ca.pem").exists()
    acc = h.access(tp.Role.OBSERVER)
    plain = h.cfg.model_copy(update={"network": h.cfg.network.model_copy(update={"tls": type(h.cfg.network.tls)()})})
    other_ca = tmp_path / "other"
    access.make_tls(other_ca, ["127.0.0.1"], ["observer"])
    assert (other_ca / "ca.pem").exists() and all(f.exists() for f in access.cert_file(other_ca, "observer"))
    users = (h.secrets / "users.txt").read_bytes()
    (other_ca / "users.txt").write_bytes(users)
    (other_ca / "users.txt").chmod(0o600)
    stranger = tp.Access(h.run, "observer", other_ca, acc.agent_ids)  # the right password, another authority
    sessions = {
        "tls": tp.open_session(tp.process_config(h.cfg, tp.Role.OBSERVER, acc)),
        "plain tcp": _outsider(plain, acc),
        "another CA": _outsider(h.cfg, stranger),
    }
    subs = {n: tp.open_channel(s, tp.Keys(h.run).status) for n, s in sessions.items()}
    first = tp.wait_sample(subs["tls"], time.monotonic() + 30.0)
    assert first is not None  # the run's own certificates and credentials: it hears the run
    assert h.wait() == "completed"
    for name in ("plain tcp", "another CA"):
        assert list(sessions[name].info.peers_zid()) == [], name
        assert subs[name].try_recv() is None, name
    for s in sessions.values():
        s.close()
    m = json.loads((h.out / "metrics.json").read_text())
    assert m["all_reached_goal"] and m["collisions"] == 0


def _forged_state_heard(start_run, name: str, tls: bool) -> tuple[int, int, int]:
    """A session with agent cf2's credentials publishes cf1's state and the world's clock
    (marked), and a probe under its own keys; an observer of the run counts the real cf1
    states, the forgeries and the probes it hears."""
    cfg = scenario(
        "swap_2.yaml",
        name=name,
        network={"tls": {"enabled": tls}, "topology": "mesh"},  # (every pair linked: each checks the other)
        duration_s=8.0,
        stop_when_all_reached=False,
        time={"mode": "realtime", "late_command": "brake"},
    )
    h = start_run(cfg, name)
    h.wait_sim_time(0.3)
    forger = tp.open_session(tp.process_config(h.cfg, tp.Role.AGENT, h.access(tp.Role.AGENT, "cf2")))
    observer = tp.open_session(tp.process_config(h.cfg, tp.Role.OBSERVER, h.access(tp.Role.OBSERVER)))
    keys = tp.Keys(h.run)
    heard = tp.open_channel(observer, f"{keys.root}/**", 1 << 16)
    fake_state = encode("state", h.run, "cf1", 7, 0.0, 0, x=[0.0, 0.0, 1.0], v=[0.0, 0.0, 0.0], r=0.07, solo=False)
    probe_key = f"{keys.root}/agent/cf2/probe"
    wait_linked(h, forger, heard, probe_key)  # (its probes under its own keys reach the observer)
    for _ in range(20):
        h.wait_sim_time(h.progress.t_s + 0.05)
        forger.put(keys.state("cf1"), fake_state)
        forger.put(keys.cell_state(cell_of([0.0, 0.0, 1.0], h.cfg.cell_m), "cf1"), fake_state)
        forger.put(keys.clock, b"forged clock")
        forger.put(probe_key, b"probe")  # under its own keys: heard
    assert h.wait() == "completed"
    real = forged = probes = 0
    for smp in tp.drain(heard):
        data = tp.payload(smp)
        if data in (fake_state, b"forged clock"):
            forged += 1
        elif data == b"probe":
            probes += 1
        elif str(smp.key_expr) == keys.state("cf1") or re.fullmatch(f"{keys.root}/cell/.*/cf1", str(smp.key_expr)):
            real += 1
    forger.close()
    observer.close()
    return real, forged, probes


def test_with_a_certificate_per_process_no_one_publishes_anothers_keys(start_run):
    real, forged, probes = _forged_state_heard(start_run, "identified", tls=True)
    assert probes == 20  # the forger is in the run: what it publishes under its own keys arrives
    assert real > 20 and forged == 0  # cf1's own states arrive; cf2's forgeries of them and of the clock do not
