"""Who may do what in a run: per-run credentials and Zenoh access-control rules.

Zenoh does the enforcing (its user-password authentication and its access control, see
https://zenoh.io/docs/manual/access-control/); this module only says what to enforce:

* every process of a run authenticates with its own user name and a random password of
  that run (``secrets/users.txt``, readable by the run's owner alone); a session without
  them cannot link to any process of the run, so it can neither publish nor subscribe;
* every session checks each message it receives (ingress): nothing outside the run's
  keys, and a command for agent ``cf4`` (``swarm/<run>/agent/cf4/command``) only from
  ``cf4`` itself or the launcher (the user's own ``swarm run``); see :func:`acl` for
  what Zenoh can and cannot check on which side of a link.

Over TCP the credentials cross the wire in Zenoh's challenge-response, never the
password itself; between machines use ``network.tls`` as well (encryption and server
authentication by certificate).
"""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarm.errors import SecretsError

if TYPE_CHECKING:
    from swarm.net.ros2.topics import Ros2Keys

USERS_FILE = "users.txt"  # Zenoh's usrpwd dictionary: one ``user:password`` per line
LAUNCHER, WORLD, RECORDER, OBSERVER, ROUTER = "launcher", "world", "recorder", "observer", "router"
ROS2_BRIDGE, ROS2 = "ros2-bridge", "ros2"  # the run's ROS 2 bridge; ROS 2 participants (swarm.ros2)


def agent_user(agent_id: str) -> str:
    """The user name of agent ``agent_id`` (prefixed: an agent may be called ``world``)."""
    return f"agent-{agent_id}"


def run_users(agent_ids: list[str]) -> list[str]:
    return [LAUNCHER, WORLD, RECORDER, OBSERVER, ROUTER, ROS2_BRIDGE, ROS2, *(agent_user(a) for a in agent_ids)]


def make_secrets(folder: Path, agent_ids: list[str]) -> Path:
    """Write a fresh password for every process of a run into ``folder/users.txt``
    (``folder`` mode 0700, the file 0600) and return the folder."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(folder, 0o700)
    path = folder / USERS_FILE
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        for user in run_users(agent_ids):
            f.write(f"{user}:{secrets.token_urlsafe(24)}\n")
    return folder


def password(folder: Path, user: str) -> str:
    """``user``'s password from ``folder/users.txt``; refuses a file others may read."""
    path = folder / USERS_FILE
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except OSError as exc:
        raise SecretsError(f"{path}: cannot read the run's credentials ({exc.strerror})") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SecretsError(f"{path}: readable by other users (mode {stat.filemode(mode)}); it must be 0600")
    for line in text.splitlines():
        name, _, pw = line.partition(":")
        if name == user and pw:
            return pw
    raise SecretsError(f"{path}: no credentials for {user!r}")


def acl(
    run: str,
    agent_ids: list[str],
    flies_commands: bool,
    identified: bool = False,
    router: str | None = None,
    ros2: Ros2Keys | None = None,
) -> dict[str, Any]:
    """Zenoh's ``access_control`` section of one process of a run. Deny by default; anyone
    linked may subscribe and query in the run; the launcher may publish anywhere in it.

    ``identified`` (mutual TLS with a certificate per process, :func:`make_tls`): both ends
    of every link know who the other is, so every process accepts from each sender only
    its own keys: the world ``world/**``, agent ``X`` ``agent/X/**``, each process its own
    liveliness token.

    Otherwise (user-password authentication alone) the side that accepts a link learns who
    connected, but the side that opened it does not (it chose whom to connect to: the
    world's endpoint, or a peer the run's gossip named), and which of two gossiping peers
    opens their link is Zenoh's choice. So anyone linked may publish the world's messages,
    the agents' states and liveliness tokens; in the process that ``flies_commands`` (the
    world, which accepts every agent's link) only agent ``X`` may publish under
    ``agent/X/`` (its commands); elsewhere (the recorder records them, agents ignore them)
    any linked session may. The launcher's land request (``land``: ``swarm.landing``) is
    accepted from anyone linked, as the launcher's link may be one it accepted.

    ``router``: ``"router"`` for the run's router (``network.topology: router``) or a
    star's bundle relay, which accepts every link it has, so it knows every sender by its
    user name and accepts from each only its own keys (as ``identified``); ``"client"``
    for every other process of ``network.topology: router``, whose one link is to the
    router: it accepts everything of the run the router forwards.

    ``ros2`` (``ros2.enabled``, through the router only): the keys of the run's ROS 2 side
    (``swarm.net.ros2.topics.ros2_keys``). Anyone linked may subscribe to the domain's data and
    liveliness; the router accepts from the bridge (``ros2-bridge``) the topics it
    publishes, its liveliness tokens and its goals for the agents (``ros2/**``), and from
    a ROS 2 participant (``ros2``) puts on exactly the goal, land and stop topics and
    liveliness tokens (its nodes, publishers and subscriptions), nothing else: not a
    drone's pose, not a key of the run. A client accepts what the router forwards."""
    root = f"swarm/{run}"
    ros_keys = [ros2.data, ros2.graph] if ros2 is not None else []
    listen = [
        "declare_subscriber",
        "declare_liveliness_subscriber",
        "liveliness_query",
        "query",
        "declare_queryable",
        "reply",
    ]
    publish = ["put", "delete", "liveliness_token"]
    who = "cert_common_names" if identified else "usernames"
    rules: list[dict[str, Any]] = [
        {
            "id": "send",
            "permission": "allow",
            "flows": ["egress"],
            "messages": [*listen, *publish],
            "key_exprs": [f"{root}/**", *ros_keys],
        },
        {
            "id": "listen",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": listen,
            "key_exprs": [f"{root}/**", *ros_keys],
        },
    ]
    # a subject with no property is any linked session (both ends of every link)
    subjects: list[dict[str, Any]] = [{"id": "anyone"}]
    policies: list[dict[str, Any]] = [{"rules": ["send", "listen"], "subjects": ["anyone"]}]
    own = {LAUNCHER: [f"{root}/**"], **{agent_user(a): [f"{root}/agent/{a}/**"] for a in agent_ids}}
    if router == "client":  # the router checked every sender
        rules.append(
            {
                "id": "shared",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": publish,
                "key_exprs": [f"{root}/**", *ros_keys],
            }
        )
        policies[0]["rules"].append("shared")
    elif identified or router == "router":
        own |= {
            WORLD: [f"{root}/world/**", f"{root}/alive/world"],
            RECORDER: [f"{root}/alive/recorder"],
            ROUTER: [f"{root}/router/**", f"{root}/alive/router"],
        }
        own |= {
            agent_user(a): [f"{root}/agent/{a}/**", f"{root}/alive/{a}", f"{root}/cell/*/*/*/{a}"] for a in agent_ids
        }
        if ros2 is not None:
            own[ROS2_BRIDGE] = [f"{root}/ros2/**", f"{root}/alive/ros2", ros2.graph, *ros2.bridge]
            own[ROS2] = list(ros2.inbound)
            rules.append(
                {
                    "id": "ros2-graph",
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": ["liveliness_token"],
                    "key_exprs": ros_keys,
                }
            )
            policies.append({"rules": ["ros2-graph"], "subjects": [ROS2]})  # (subject ROS2: below)
    else:
        shared = [f"{root}/{k}" for k in ("world/**", "agent/*/state", "cell/**", "router/**", "alive/*", "land")]
        if not flies_commands:
            shared.append(f"{root}/agent/*/command")
        rules.append(
            {"id": "shared", "permission": "allow", "flows": ["ingress"], "messages": publish, "key_exprs": shared}
        )
        policies[0]["rules"].append("shared")
    for user, keys in own.items():
        rules.append({"id": user, "permission": "allow", "flows": ["ingress"], "messages": publish, "key_exprs": keys})
        subjects.append({"id": user, who: [user]})
        policies.append({"rules": [user], "subjects": [user]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def cert_file(folder: Path, user: str) -> tuple[Path, Path]:
    """(certificate, private key) of ``user`` in a run's secrets folder (``make_tls``)."""
    return folder / "tls" / f"{user}.pem", folder / "tls" / f"{user}.key"


def make_tls(folder: Path, hosts: list[str], users: list[str], days: int = 30) -> None:
    """A certificate authority of the run's own (``folder/ca.pem``) and, for every user of
    the run, a certificate it signs whose common name is the user's name and whose
    subject names are ``hosts`` (IP addresses or DNS names), in ``folder/tls/`` (keys
    0600). Each process listens and connects with its own certificate (mutual TLS), so
    both ends of every link know who the other is, and the access-control rules can name
    the sender of every message (:func:`acl` with ``identified``)."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.UTC)
    until = now + datetime.timedelta(days=days)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "c3swarm run CA")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                key_cert_sign=True,
                crl_sign=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    (folder / "tls").mkdir(mode=0o700, parents=True, exist_ok=True)
    (folder / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    names = _subject_names(hosts)
    for user in users:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = _leaf(x509.CertificateBuilder(), user, names, key, ca_name, now, until).sign(ca_key, hashes.SHA256())
        cert_path, key_path = cert_file(folder, user)
        cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(
                key.private_bytes(
                    serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
                )
            )


def _subject_names(hosts: list[str]) -> list[Any]:
    import ipaddress

    from cryptography import x509

    out: list[Any] = []
    for h in dict.fromkeys([*hosts, "localhost", "127.0.0.1"]):
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            out.append(x509.DNSName(h))
    return out


def _leaf(b: Any, user: str, names: list[Any], key: Any, ca_name: Any, now: Any, until: Any) -> Any:
    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    return (
        b.subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, user)]))
        .issuer_name(ca_name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
        )
    )
