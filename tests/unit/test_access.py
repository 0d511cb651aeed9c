"""What the run's access control says (swarm.net.access), without Zenoh: credentials files,
and which user may publish which key in each process's rules."""

import stat
from fnmatch import fnmatch

import pytest

from swarm.net import access

IDS = ["cf1", "cf2"]


def test_secrets_are_per_user_random_and_private(tmp_path):
    folder = access.make_secrets(tmp_path / "s", IDS)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_IMODE((folder / access.USERS_FILE).stat().st_mode) == 0o600
    pw = {u: access.password(folder, u) for u in access.run_users(IDS)}
    assert len(set(pw.values())) == len(pw) and all(len(p) >= 24 for p in pw.values())
    again = access.make_secrets(tmp_path / "t", IDS)
    assert access.password(again, "world") != pw["world"]  # a new run, new passwords
    with pytest.raises(access.SecretsError, match="no credentials"):
        access.password(folder, "agent-cf9")


def test_a_credentials_file_others_may_read_is_refused(tmp_path):
    folder = access.make_secrets(tmp_path / "s", IDS)
    (folder / access.USERS_FILE).chmod(0o644)
    with pytest.raises(access.SecretsError, match="readable by other users"):
        access.password(folder, "world")
    with pytest.raises(access.SecretsError, match="cannot read"):
        access.password(tmp_path / "missing", "world")


def _may_publish(rules: dict, user: str, key: str, identified: bool) -> bool:
    """Whether ``rules`` let ``user``'s session (or, unidentified, anyone's) put ``key``."""
    by_id = {r["id"]: r for r in rules["rules"]}
    subjects = {s["id"]: s for s in rules["subjects"]}
    for pol in rules["policies"]:
        for sid in pol["subjects"]:
            names = subjects[sid].get("cert_common_names" if identified else "usernames")
            if names is not None and user not in names:
                continue
            for rid in pol["rules"]:
                r = by_id[rid]
                if (
                    "ingress" in r["flows"]
                    and "put" in r["messages"]
                    and any(fnmatch(key, k.replace("**", "*")) for k in r["key_exprs"])
                ):
                    return True
    return False


def test_at_the_world_only_an_agent_commands_its_own_drone():
    world = access.acl("r", IDS, flies_commands=True)
    cmd = "swarm/r/agent/cf1/command"
    assert _may_publish(world, "agent-cf1", cmd, False)
    assert not _may_publish(world, "agent-cf2", cmd, False)
    assert not _may_publish(world, "observer", cmd, False)
    assert _may_publish(world, "launcher", cmd, False)
    assert not _may_publish(world, "agent-cf1", "swarm/other-run/agent/cf1/command", False)
    recorder = access.acl("r", IDS, flies_commands=False)
    assert _may_publish(recorder, "anyone-linked", cmd, False)  # it records what the world decides on


def test_with_a_certificate_per_process_every_key_has_one_publisher():
    rules = access.acl("r", IDS, flies_commands=False, identified=True)
    assert _may_publish(rules, "world", "swarm/r/world/clock", True)
    assert not _may_publish(rules, "agent-cf2", "swarm/r/world/clock", True)
    assert _may_publish(rules, "agent-cf2", "swarm/r/agent/cf2/state", True)
    assert not _may_publish(rules, "agent-cf2", "swarm/r/agent/cf1/state", True)
    assert not _may_publish(rules, "observer", "swarm/r/agent/cf1/state", True)


def test_at_the_router_a_script_orders_only_the_drones_it_may_steer():
    rules = access.acl("r", ["cf1", "cf2", "cf3"], flies_commands=False, router="router", steerable=["cf1", "cf2"])
    assert _may_publish(rules, "script", "swarm/r/script/order/cf1", False)
    assert _may_publish(rules, "script", "swarm/r/script/order/cf2", False)
    assert not _may_publish(rules, "script", "swarm/r/script/order/cf3", False)
    assert _may_publish(rules, "script", "swarm/r/script/done", False)
    assert _may_publish(rules, "script", "swarm/r/alive/script", False)
    others = ("swarm/r/agent/cf1/command", "swarm/r/agent/cf1/report", "swarm/r/ros2/goal/cf1", "swarm/r/world/clock")
    for key in others:
        assert not _may_publish(rules, "script", key, False), key
    assert not _may_publish(rules, "agent-cf1", "swarm/r/script/order/cf1", False)
    assert _may_publish(rules, "agent-cf1", "swarm/r/agent/cf1/report", False)
    off = access.acl("r", ["cf1"], flies_commands=False, router="router")  # no script: nothing of it
    assert not _may_publish(off, "script", "swarm/r/script/order/cf1", False)
