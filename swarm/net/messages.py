"""Wire messages: msgpack maps with a common header and checked bodies.

Every message carries ``ver`` (schema version), ``kind``, ``run`` (run id), ``src``
(sender id), ``seq`` (per-sender sequence number), ``t`` (sim time [s]) and ``k``
(control tick). Vectors travel as msgpack binaries of little-endian float64 (a list of
floats costs about 14 us to decode per hundred; these cost 2): positions [m, world],
velocities [m/s, world], quaternions scalar-last (see :mod:`swarm.rotation`), body rates
[rad/s, body], forces [N]. Obstacle items keep plain lists (few, and read as records).
:func:`decode` checks types, shapes and finiteness and raises :class:`DecodeError`;
receivers drop and count such messages, never crash.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import repeat
from typing import Any

import msgpack
import numpy as np

from swarm.errors import DecodeError
from swarm.model import all_finite
from swarm.net import statewire
from swarm.realism.sensing import MocapFrame

VERSION = 11
"""The schema version every message carries; a message of another is dropped and counted
(what each version added: docs/design.md, "Processes and messages")."""

# kind -> {field: spec}; spec is a vector length, "f" float, "i" int, "s" str, "b" bool,
# "vf" variable-length vector, "ls" list of str, "obs" obstacle list (vectors: float64 binaries)
SCHEMAS: dict[str, dict[str, Any]] = {
    "measurement": {"x": 3, "v": 3, "q": 4, "w": 3},
    # what a neighbour needs of an agent: its body centre, velocity and bounding radius, and
    # whether it is not doing its share of a pair's avoidance now (its last filter call was
    # not a clean solve, or it flies unfiltered): then the neighbour takes all of it
    "state": {"x": 3, "v": 3, "r": "f", "solo": "b", "sd": 2},
    # what the world needs (the command of the agent's level), then the filter's report
    # of this tick for the record: status, intervention |u - u_ref|, solve time [us],
    # the names and h of the rows, and the agent's running counts
    "command": {
        "level": "s",
        "u": "vf",
        "intervention": "f",
        "status": "s",
        "solve_us": "f",
        "row_ids": "ls",
        "h_rows": "vf",
        "min_h": "f",
        "infeasible": "i",
        "goal_reached": "b",
        "dropped": "i",
        # the state the agent acted on (world.realism.sensing: its estimate): centre of mass [m],
        # its velocity [m/s], world, its position [m] and velocity [m/s] deviations and its age [s];
        # empty when it acts on the world's measurement
        "est": "vf",
        # the safety monitor (swarm.safety.monitor): its action now (0 none, 1 warn, 2 slow, 3 hold,
        # 4 land), the checks that breached (a bit each), and the largest live noise margin of a row [m]
        "monitor": "i",
        "breaches": "i",
        "live_margin": "f",
        # a safety filter plugin (swarm.safety.external): why its command was replaced by the built-in
        # safe command at this tick ("" none: raised, non_finite, out_of_limits, overrun, failed), and
        # the ticks so far it was
        "fallback": "s",
        "fallbacks": "i",
        # the same of a reference controller plugin (swarm.reference), replaced by the path tracker's reference
        "ctrl_fallback": "s",
        "ctrl_fallbacks": "i",
    },
    # world -> one simulated agent with neighbours by cells (key world/<id>/tick): its
    # measurement, the obstacles, the live agents within its near radius (the states tick k
    # uses: theirs of tick k-1), the agents whose liveliness the world has seen go (in a star
    # the agents hear no other agent's liveliness), and whether the run is over. Its size does
    # not grow with N (but for the dead).
    "tick": {"x": 3, "v": 3, "q": 4, "w": 3, "near": "ls", "items": "obs", "gone": "ls", "done": "b", "frames": "vf"},
    "clock": {
        "live": "ls",
        "done": "b",
        "ids": "ls",
        "xvr": "vf",
        "meas_ids": "ls",
        "meas": "vf",
        "items": "obs",
        "solo": "ls",
        "frames": "vf",
        "skipped": "i",
    },
    "status": {
        "rtf": "f",
        "min_sep": "f",
        "min_clear": "f",
        "collisions": "i",
        "late": "i",
        "dropped": "i",
        "live": "ls",
        "done": "b",
        "infeasible": "i",
        "stalls": "i",
        "dead": "ls",
        "acting": "i",
        # the agents whose safety filter plugin has had its command replaced, and how many ticks each
        "fallback_ids": "ls",
        "fallback_ticks": "vf",
    },
    # a contact that began at this tick; dead: one of the two is a dead agent's drone (landing,
    # or left to the firmware), counted apart from collisions among live agents
    "collision": {"a": "s", "b": "s", "dead": "b"},
    # a lockstep tick that waited longer than time.stall_warn_s for these agents' commands
    "stall": {"agents": "ls", "wait_s": "f"},
    # the ROS 2 bridge -> an agent (swarm.ros2.goals): fly to x ("goal"), by x ("goal_relative"),
    # climb to x[2] ("takeoff"), land, or hold ("stop"), in about duration seconds (0: at its own speed)
    "goal": {"action": "s", "x": 3, "duration": "f"},
    # the launcher -> the world and every agent (key land): land every drone and end the run
    # once they are down; why (e.g. "Ctrl-C")
    "land": {"why": "s"},
    # a script -> an agent (swarm.script): takeoff (to height x[2] above where it is), goto x, land, stop
    "order": {"order": "i", "action": "s", "x": 3, "yaw": "f", "speed": "f"},
    # an agent -> the script and the record: its order taken (the goal it flies to), refused, or arrived
    "report": {"order": "i", "action": "s", "x": 3, "state": "s", "why": "s"},
    # a script -> the world: the experiment is over, end the run
    "end": {"reason": "s"},
}
# The clock of tick k (world -> all) is the one message a simulated agent needs per tick:
#   live, done       the agents the world expects answers from; the run is over
#   ids, xvr         the roster: per drone its body centre [m], velocity [m/s] and radius [m]
#   solo             the drones of the roster not doing their share (dead, unfiltered, or their
#                    last command not a clean filter solve): the others take all of each pair
#   meas_ids, meas   per simulated drone its measurement x [m], v [m/s], q (x, y, z, w), w [rad/s]
#   items            the obstacles at tick k
#   frames           world.realism.sensing: the motion-capture frames that arrived since the last
#                    tick, FRAME floats each (FRAME_FIELDS); the tick's own: its drone's alone
#   skipped          the ticks before k the world flew unpublished (0 but in a realtime run with real
#                    drones whose world fell behind the wall clock: time.max_lag_s)
# Real drones' measurements come from the motion-capture relay on their own key.
CLOCK_XVR, CLOCK_MEAS = 7, 13
FRAME_FIELDS = ("drone", "seq", "t_arrival", "x", "y", "z", "qx", "qy", "qz", "qw")
"""A motion-capture frame on the wire: the drone's index in the clock's ``meas_ids`` (0 in its own
tick), the frame number, its arrival time [s] (its capture time less the latency the agent
knows), its position [m, world] and attitude (scalar-last), as measured."""
FRAME = len(FRAME_FIELDS)
HEADER = ("ver", "kind", "run", "src", "seq", "t", "k")
_NUMBER = (float, int)
_F8 = np.dtype("<f8")  # the vectors' wire type


@dataclass(frozen=True)
class Message:
    """A decoded message: the header and the body fields (vectors as numpy arrays)."""

    kind: str
    run: str
    src: str
    seq: int
    t: float
    k: int
    body: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> Any:
        return self.body[name]


@dataclass(frozen=True)
class StateBody:
    """An agent's state message body: what a neighbour needs of it."""

    x_b_w: np.ndarray  # (3,) m, world: body centre
    v_b_w: np.ndarray  # (3,) m/s, world: its velocity
    radius_m: float  # bounding radius
    solo: bool  # not doing its share of a pair's avoidance now (its neighbours take all of it)
    sd: tuple[float, float] = (0.0, 0.0)  # its estimate's position [m] and velocity [m/s] deviation (largest axis)

    def fields(self) -> dict[str, Any]:
        return {"x": self.x_b_w, "v": self.v_b_w, "r": self.radius_m, "solo": self.solo, "sd": self.sd}


@dataclass(frozen=True)
class CommandBody:
    """An agent's command message body: the command of its level, and the filter's report of
    this tick for the record (schema ``command``)."""

    level: str  # "attitude": u = roll [rad], pitch [rad], yaw rate [rad/s], thrust [N]; "rotors": f (4,) [N]
    u: np.ndarray  # (4,)
    status: str  # the filter's status ("ok", "infeasible", "failed"; "ok" when unfiltered)
    intervention: float = 0.0  # |u - u_ref| in input units
    solve_us: float = 0.0  # the filter call's time [us]
    row_ids: tuple[str, ...] = ()  # each row's name
    h_rows: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (n,) m^2/s: h of each row
    min_h: float = 1e9  # m^2/s: the smallest exact h so far (1e9: none yet)
    infeasible: int = 0  # ticks so far that were not a clean solve
    goal_reached: bool = False
    est: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (9,) the estimate it acted on, or (0,)
    monitor: int = 0  # the safety monitor's action (swarm.safety.monitor.Action)
    breaches: int = 0  # the checks that breached (swarm.safety.monitor.Breach bits)
    live_margin: float = 0.0  # m: the largest live noise margin of a row
    fallback: str = ""  # a plugin filter's command replaced at this tick, why (swarm.safety.external.Fallback)
    fallbacks: int = 0  # ticks so far its command was replaced
    ctrl_fallback: str = ""  # a reference controller plugin's reference replaced at this tick, why
    ctrl_fallbacks: int = 0  # ticks so far its reference was replaced

    @staticmethod
    def zero(level: str = "attitude") -> CommandBody:
        """Motors off: a zero command of ``level``, a clean tick."""
        return CommandBody(level, np.zeros(4), "ok")

    def fields(self) -> dict[str, Any]:
        return {
            "level": self.level,
            "u": self.u,
            "intervention": self.intervention,
            "status": self.status,
            "solve_us": self.solve_us,
            "row_ids": list(self.row_ids),
            "h_rows": self.h_rows,
            "min_h": self.min_h,
            "infeasible": self.infeasible,
            "goal_reached": self.goal_reached,
            "est": self.est,
            "monitor": self.monitor,
            "breaches": self.breaches,
            "live_margin": self.live_margin,
            "fallback": self.fallback,
            "fallbacks": self.fallbacks,
            "ctrl_fallback": self.ctrl_fallback,
            "ctrl_fallbacks": self.ctrl_fallbacks,
        }


def encode_command(run: str, src: str, seq: int, t: float, k: int, body: CommandBody, dropped: int = 0) -> bytes:
    """A command message of ``body``, with the sender's count of ``dropped`` messages."""
    return encode("command", run, src, seq, t, k, dropped=dropped, **body.fields())


def encode_state(run: str, src: str, seq: int, t: float, k: int, body: StateBody) -> bytes:
    """A state message of ``body`` (a fixed binary record: :mod:`swarm.net.statewire`)."""
    return statewire.encode_state(run, src, seq, t, k, body.x_b_w, body.v_b_w, body.radius_m, body.solo, body.sd)


def encode(kind: str, run: str, src: str, seq: int, t: float, k: int, **body: Any) -> bytes:
    """msgpack bytes of a message; vector fields (arrays or lists) become float64 binaries."""
    if kind == "state":  # a fixed binary record (swarm.net.statewire), not msgpack
        return statewire.encode_state(
            run, src, seq, t, k, body["x"], body["v"], body["r"], body.get("solo", False), body.get("sd", (0.0, 0.0))
        )
    schema = SCHEMAS.get(kind)
    if schema is None:
        raise ValueError(f"unknown message kind {kind!r}")
    out: dict[str, Any] = {"ver": VERSION, "kind": kind, "run": run, "src": src, "seq": seq, "t": float(t), "k": k}
    for name, value in body.items():
        spec = schema.get(name)
        if type(spec) is int or spec == "vf":
            value = np.asarray(value, dtype=_F8).tobytes()
        elif isinstance(value, np.ndarray):
            value = value.tolist()
        out[name] = value
    return msgpack.packb(out, use_bin_type=True)


def _float(name: str, x: Any) -> float:
    if type(x) not in _NUMBER or not math.isfinite(x):
        raise DecodeError(f"{name}: expected a finite number, got {type(x).__name__}")
    return float(x)


def _floats(name: str, x: Any, n: int | None) -> np.ndarray:
    """A vector field: a binary of ``n`` (any number if None) little-endian float64, all finite."""
    if type(x) is not bytes or len(x) % 8 or (n is not None and len(x) != 8 * n):
        raise DecodeError(f"{name}: expected {n if n is not None else 'some'} float64 as a binary")
    arr = np.frombuffer(bytearray(x), _F8)  # writable (its own buffer)
    if not all_finite(arr):
        raise DecodeError(f"{name}: expected finite numbers")
    return arr


def _vector(name: str, x: Any, n: int) -> np.ndarray:
    """A short vector given as a list (obstacle items): ``n`` finite numbers."""
    if type(x) is not list or len(x) != n:
        raise DecodeError(f"{name}: expected a list of {n} numbers")
    for e in x:  # exact types: a bool is not a number here
        if type(e) not in _NUMBER or not math.isfinite(e):
            raise DecodeError(f"{name}: expected finite numbers")
    return np.array(x, dtype=float)


def _obstacles(x: Any) -> list[dict[str, Any]]:
    if not isinstance(x, list):
        raise DecodeError("items: expected a list")
    out = []
    for i, o in enumerate(x):
        if not isinstance(o, dict) or not isinstance(o.get("id"), str) or o.get("shape") not in ("sphere", "cylinder"):
            raise DecodeError(f"items[{i}]: expected an obstacle with id and shape")
        r = _float(f"items[{i}].r", o.get("r"))
        if r < 0:
            raise DecodeError(f"items[{i}].r: negative radius")
        out.append(
            {
                "id": o["id"],
                "shape": o["shape"],
                "r": r,
                "c": _vector(f"items[{i}].c", o.get("c"), 3),
                "cd": _vector(f"items[{i}].cd", o.get("cd"), 3),
                "a": _vector(f"items[{i}].a", o.get("a"), 3),
            }
        )
    return out


def _int(name: str, x: Any) -> int:
    if type(x) is not int:  # (a bool is not an integer here)
        raise DecodeError(f"{name}: expected an integer")
    return x


def _str(name: str, x: Any) -> str:
    if type(x) is not str:
        raise DecodeError(f"{name}: expected a string")
    return x


def _bool(name: str, x: Any) -> bool:
    if type(x) is not bool:
        raise DecodeError(f"{name}: expected a boolean")
    return x


def _strs(name: str, x: Any) -> list[str]:
    if type(x) is not list or not all(map(isinstance, x, repeat(str))):
        raise DecodeError(f"{name}: expected a list of strings")
    return x  # (unpackb built it: nobody else holds it)


def _checker(spec: Any) -> Any:
    """The function that checks and converts one field of ``spec``: (name, value) -> value."""
    if type(spec) is int:
        return lambda name, x: _floats(name, x, spec)
    simple = {"f": _float, "i": _int, "s": _str, "b": _bool, "ls": _strs, "obs": lambda name, x: _obstacles(x)}
    return simple.get(spec, lambda name, x: _floats(name, x, None))  # "vf"


# kind -> ((field, checker), ...): decode looks each field's check up once, not per message
_CHECKS = {kind: tuple((name, _checker(spec)) for name, spec in fields.items()) for kind, fields in SCHEMAS.items()}


def _checks(kind: str, fields: tuple[str, ...] | None) -> tuple[tuple[str, Any], ...] | None:
    """The (field, checker) pairs of ``kind``, or of its ``fields`` only."""
    checks = _CHECKS.get(kind)
    if checks is None or fields is None:
        return checks
    key = (kind, fields)
    some = _SOME_CHECKS.get(key)
    if some is None:
        some = _SOME_CHECKS[key] = tuple((name, check) for name, check in checks if name in fields)
    return some


_SOME_CHECKS: dict[tuple[str, tuple[str, ...]], tuple[tuple[str, Any], ...]] = {}


def decode(
    payload: bytes, run: str, kinds: tuple[str, ...] | None = None, fields: tuple[str, ...] | None = None
) -> Message:
    """Decode and check a message of this ``run`` (and one of ``kinds`` if given). With
    ``fields`` only those body fields are checked and kept (a receiver that reads only
    them: the world reads a command's level, input and status, not the filter's report,
    which the recorder checks); the header is always checked. A state is a
    :mod:`swarm.net.statewire` record, checked whole."""
    if payload[:3] == statewire.STATE_MAGIC:
        return _state_message(payload, run, kinds)
    try:
        m = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several types on garbage
        raise DecodeError(f"not msgpack ({type(exc).__name__})") from None
    if type(m) is not dict:
        raise DecodeError("not a map")
    for h in HEADER:
        if h not in m:
            raise DecodeError(f"missing header field {h!r}")
    if m["ver"] != VERSION:
        raise DecodeError(f"schema version {m['ver']!r}, expected {VERSION}")
    if m["run"] != run:
        raise DecodeError(f"run {m['run']!r}, expected {run!r}")
    kind = m["kind"]
    checks = _checks(kind, fields) if type(kind) is str else None
    if checks is None or (kinds is not None and kind not in kinds):
        raise DecodeError(f"unexpected kind {kind!r}")
    if type(m["src"]) is not str or type(m["seq"]) is not int or type(m["k"]) is not int:
        raise DecodeError("header: src must be str, seq and k int")
    t = _float("t", m["t"])
    try:
        body = {name: check(name, m[name]) for name, check in checks}
    except KeyError as exc:
        raise DecodeError(f"{kind}: missing field {exc.args[0]!r}") from None
    if kind == "clock" and len(body) == len(_CHECKS["clock"]):  # (a whole clock: its sizes agree)
        n, n_meas = len(body["ids"]), len(body["meas_ids"])
        if body["xvr"].size != CLOCK_XVR * n or body["meas"].size != CLOCK_MEAS * n_meas:
            raise DecodeError(
                f"clock: xvr of {body['xvr'].size} for {n} ids, meas of {body['meas'].size} for {n_meas} meas_ids"
            )
    return Message(kind, m["run"], m["src"], m["seq"], t, m["k"], body)


def _state_message(payload: bytes, run: str, kinds: tuple[str, ...] | None) -> Message:
    if kinds is not None and "state" not in kinds:
        raise DecodeError("unexpected kind 'state'")
    f = statewire.read_state(payload, run)
    body = {"x": np.array(f[7:10]), "v": np.array(f[10:13]), "r": f[13], "solo": f[2] == 1, "sd": (f[14], f[15])}
    return Message("state", run, f[16].rstrip(b"\0").decode(), f[3], f[6], f[5], body)


def warm_up() -> None:
    """Decode a message with vectors and a state now: the first decodes load the compiled
    finiteness check of the vectors, which a process should pay before its first tick, not
    in it."""
    z = np.zeros(3)
    decode(encode("measurement", "", "warm-up", 0, 0.0, 0, x=z, v=z, q=np.array([0, 0, 0, 1.0]), w=z), "")
    decode(encode("state", "", "warm-up", 0, 0.0, 0, x=z, v=z, r=0.0, solo=False), "")


def record_of(msg: Message) -> dict[str, Any]:
    """The header and body of a decoded message as one dict (vectors stay numpy arrays)."""
    return {"kind": msg.kind, "src": msg.src, "seq": msg.seq, "t": msg.t, "k": msg.k, **msg.body}


def to_json(msg: Message) -> dict[str, Any]:
    """A JSON-ready dict of a decoded message (:func:`record_of` with lists for arrays)."""

    def conv(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, list):
            return [conv(e) for e in v]
        if isinstance(v, dict):
            return {k: conv(e) for k, e in v.items()}
        return v

    return conv(record_of(msg))


def _measured(meas: Any, i: int) -> dict[str, Any]:
    """Row ``i`` of a clock's ``meas`` (array or list) as measurement fields."""
    row = meas[CLOCK_MEAS * i : CLOCK_MEAS * (i + 1)]
    return {"x": row[0:3], "v": row[3:6], "q": row[6:10], "w": row[10:13]}


def clock_measurement(clock: Message, agent_id: str) -> Message | None:
    """The measurement of ``agent_id`` that ``clock`` carries, as a measurement message
    of the clock's tick with its motion-capture frames (None when the clock carries none for it)."""
    try:
        i = clock["meas_ids"].index(agent_id)
    except ValueError:
        return None
    body = _measured(clock["meas"], i)
    body["frames"] = frames_of(clock["frames"], i)
    return Message("measurement", clock.run, clock.src, clock.seq, clock.t, clock.k, body)


def frames_wire(frames: list[tuple[int, Any]]) -> np.ndarray:
    """``(drone index, frame)`` pairs (frames: ``swarm.realism.MocapFrame``) as a message's
    ``frames`` field (:data:`FRAME_FIELDS`)."""
    out = np.empty((len(frames), FRAME))
    for row, (i, f) in zip(out, frames, strict=True):
        row[0], row[1], row[2] = i, f.seq, f.t_arrival_s
        row[3:6] = f.x_w
        row[6:10] = f.q
    return out.ravel()


def frames_of(wire: np.ndarray, drone: int) -> list[MocapFrame]:
    """The frames of ``drone`` (its index in the clock's ``meas_ids``, 0 in its own tick) in a
    message's ``frames`` field, as the receiving agent knows them: its capture time is not on the
    wire (the field holds the arrival time too); malformed lengths give none (the message was
    checked finite)."""
    if wire.size % FRAME:
        return []
    rows = wire.reshape(-1, FRAME)
    return [
        MocapFrame(0, int(r[1]), float(r[2]), float(r[2]), r[3:6].copy(), r[6:10].copy())
        for r in rows
        if int(r[0]) == drone
    ]


def expand_record(record: dict[str, Any]) -> list[dict[str, Any]]:
    """A recorded clock (a :func:`to_json` dict) as the records it bundles: a
    ``measurement`` record per drone it measured (with its ``agent``) and an
    ``obstacles`` record, after the clock itself; any other record as itself. Readers of
    a run (metrics, reports) see one measurement per drone and tick, whatever carried it."""
    if record.get("kind") != "clock" or "meas_ids" not in record:
        return [record]
    head: dict[str, Any] = {k: record[k] for k in ("src", "seq", "t", "k") if k in record}
    out = [record]
    for i, aid in enumerate(record["meas_ids"]):
        out.append({**head, "kind": "measurement", "agent": aid, **_measured(record["meas"], i)})
    out.append({**head, "kind": "obstacles", "items": record["items"]})
    return out


def measurement_agent(record: dict[str, Any]) -> str:
    """Agent id of a measurement record: its ``agent`` (bundled in a clock) or the id in
    its key ``.../world/<id>/measurement``."""
    return str(record.get("agent") or record["topic"].split("/")[-2])


# what each field means, with its unit and frame, for the recorded channels' JSON schemas
FIELD_DOCS: dict[str, str] = {
    "kind": "message kind",
    "src": "sender id",
    "seq": "sender's sequence number",
    "t": "sim time [s]",
    "k": "control tick",
    "x": "position [m, world] (a state's and the roster's: the body centre)",
    "v": "velocity [m/s, world]",
    "q": "attitude quaternion (x, y, z, w), body to world",
    "w": "body rates [rad/s, body]",
    "r": "bounding radius [m]",
    "solo": "not doing its share of the avoidance (whole rows for it)",
    "level": "command level (attitude or rotor)",
    "u": "command: F [N, world] (attitude) or rotor thrusts [N]",
    "intervention": "|u - u_ref|, the filter's change of the reference [N]",
    "status": "filter status",
    "solve_us": "filter call time [us]",
    "row_ids": "obstacle or agent id of each barrier row",
    "h_rows": "barrier value h of each row [m^2/s]",
    "min_h": "smallest h of the filter's rows so far this run, escape rows left out [m^2/s] (1e9: none yet); "
    "this tick's are h_rows",
    "infeasible": "infeasible ticks so far",
    "goal_reached": "the agent reached its goal",
    "dropped": "messages dropped so far",
    "near": "agents whose states this tick uses",
    "gone": "agents whose liveliness the world has seen go",
    "items": "obstacles: id, shape, centre c [m, world], velocity cd [m/s, world], radius r [m], unit axis a",
    "done": "the run is over",
    "live": "agents the world expects answers from",
    "ids": "roster drone ids",
    "xvr": "roster: per drone body centre [m], velocity [m/s], radius [m] (7 floats)",
    "meas_ids": "simulated drones of meas",
    "meas": "per simulated drone x [m], v [m/s], q, w [rad/s] (13 floats)",
    "skipped": "ticks before this one the world flew unpublished (realtime, behind its real drones)",
    "rtf": "real-time factor",
    "min_sep": "closest pair of body centres so far [m]",
    "min_clear": "closest body centre to an obstacle surface so far [m]",
    "collisions": "contacts so far",
    "late": "late ticks so far",
    "stalls": "stalled ticks so far",
    "dead": "agents declared dead",
    "acting": "agents whose safety monitor slows, holds or lands their drone now (their newest command's)",
    "a": "one side of the contact (agent or obstacle id)",
    "b": "other side of the contact",
    "agents": "agents the tick waited for",
    "wait_s": "how long it waited [s]",
    "action": "goal or goto (fly to x), goal_relative (by x), takeoff (climb to x's height), land or stop "
    "(hold where it is)",
    "order": "the script's number of the order",
    "duration": "how long the move should take [s] (0: at the drone's own speed_mps)",
    "yaw": "yaw asked [rad, world] (simulated drones hold their yaw: not flown)",
    "speed": "cruise speed asked [m/s] (0: the drone's own speed_mps)",
    "state": "taken (x: the goal flown to), refused (why), or arrived (within goal_tolerance_m of x)",
    "why": "why the launcher asks every drone to land (e.g. Ctrl-C); why an order was refused (empty otherwise)",
    "reason": "why the script ended the run",
    "frames": "motion-capture frames since the last tick (world.realism.sensing): per frame drone index, frame "
    "number, arrival time [s], position [m, world], attitude (x, y, z, w) (10 floats)",
    "est": "the state the agent acted on, its estimate with world.realism.sensing: centre of mass [m] and "
    "velocity [m/s], world, the largest axis's position [m] and velocity [m/s] standard deviations, and the "
    "estimate's age [s] since its last motion-capture frame (9 floats; none without an estimate)",
    "monitor": "the safety monitor's action: 0 none, 1 warn, 2 slow, 3 hold, 4 land (swarm.safety.monitor)",
    "breaches": "the safety monitor's checks that breached this tick, a bit each: 1 estimate_std, 2 estimate_age, "
    "4 estimate_lost, 8 neighbour_std, 16 neighbour_age, 32 infeasible, 64 disturbance, 128 world_late, "
    "256 tick_overrun",
    "live_margin": "the largest extra radius a filter row kept for the estimates' noise this tick [m]",
    "sd": "the standard deviations of the state's position [m] and velocity [m/s] (its estimate's, largest axis)",
    "fallback": "why the safety filter plugin's command was replaced by the built-in safe command this tick: "
    "raised, non_finite, out_of_limits, overrun, failed (empty: not replaced; swarm.safety.external)",
    "fallbacks": "ticks so far the safety filter plugin's command was replaced by the built-in safe command",
    "ctrl_fallback": "why the reference controller plugin's reference was replaced by the path tracker's this "
    "tick: raised, non_finite, out_of_limits, overrun (empty: not replaced; swarm.reference)",
    "ctrl_fallbacks": "ticks so far the reference controller plugin's reference was replaced by the path tracker's",
    "fallback_ids": "agents whose safety filter or reference controller plugin has been replaced by the built-in",
    "fallback_ticks": "per agent of fallback_ids, the ticks so far its plugins' commands were replaced (both counted)",
}
_ITEM_SCHEMA = {
    "type": "object",
    "properties": {
        "id": {"type": "string"},
        "shape": {"type": "string", "enum": ["sphere", "cylinder"]},
        "c": {"type": "array", "items": {"type": "number"}, "description": "centre [m, world]"},
        "cd": {"type": "array", "items": {"type": "number"}, "description": "velocity [m/s, world]"},
        "r": {"type": "number", "description": "radius [m]"},
        "a": {"type": "array", "items": {"type": "number"}, "description": "unit axis (zeros: a sphere)"},
    },
}


def _field_schema(spec: Any) -> dict[str, Any]:
    if type(spec) is int:
        return {"type": "array", "items": {"type": "number"}, "minItems": spec, "maxItems": spec}
    simple: dict[str, dict[str, Any]] = {
        "f": {"type": "number"},
        "i": {"type": "integer"},
        "s": {"type": "string"},
        "b": {"type": "boolean"},
        "ls": {"type": "array", "items": {"type": "string"}},
        "obs": {"type": "array", "items": _ITEM_SCHEMA},
    }
    return simple.get(spec, {"type": "array", "items": {"type": "number"}})  # "vf"


def json_schema(kind: str) -> dict[str, Any]:
    """The JSON schema of a recorded message of ``kind`` (:func:`record_of`'s fields:
    header and body, each with its description and unit), as Foxglove lists them."""
    header = {
        "kind": {"type": "string", "const": kind},
        "src": {"type": "string"},
        "seq": {"type": "integer"},
        "t": {"type": "number"},
        "k": {"type": "integer"},
    }
    props = header | {name: _field_schema(spec) for name, spec in SCHEMAS[kind].items()}
    for name, p in props.items():
        if name in FIELD_DOCS:
            p["description"] = FIELD_DOCS[name]
    return {"title": f"c3swarm.{kind}", "type": "object", "properties": props, "required": list(props)}
