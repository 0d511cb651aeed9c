"""Seeing a run: Foxglove channels in run.mcap, the live server, and ``swarm view`` in
headless Chromium. Real processes, real Foxglove and Rerun servers, a real browser."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from swarm.runs.launch import RunHandle, free_port
from swarm.runs.runfiles import read_records

from .conftest import CONFIGS, scenario

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def crash_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The single-sphere scene flown unfiltered: the drone hits the sphere."""
    cfg = scenario("single_static_sphere.yaml", defaults={"filter": {"enabled": False}}, duration_s=4.0)
    h = RunHandle.start(cfg, tmp_path_factory.mktemp("views") / "crash")
    try:
        assert h.wait() in ("completed", "time limit reached") or h.out.joinpath("metrics.json").exists()
    finally:
        if h.reason is None:
            h.finish("test teardown")
    return h.out


def _decoded(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, proto in reader.iter_decoded_messages(topics=["/tf", "/scene", "/log"]):
            out.setdefault(channel.topic, []).append((schema.name, message.log_time, proto))
    return out


def test_run_mcap_has_foxglove_channels_that_match_the_run(crash_run: Path) -> None:
    records = read_records(crash_run / "run.mcap")
    clocks = {int(r["t"] * 1e9): r for r in records if r["kind"] == "clock"}
    collisions = [r for r in records if r["kind"] == "collision"]
    assert collisions, "the unfiltered drone should have hit the sphere"
    fox = _decoded(crash_run / "run.mcap")
    assert {s for s, _, _ in fox["/tf"]} == {"foxglove.FrameTransforms"}
    assert {s for s, _, _ in fox["/scene"]} == {"foxglove.SceneUpdate"}
    assert {s for s, _, _ in fox["/log"]} == {"foxglove.Log"}
    assert len(fox["/tf"]) == len(clocks)  # a frame per clock, at the recorded rate
    for _, log_ns, tf in fox["/tf"]:
        c = clocks[log_ns]
        assert [t.child_frame_id for t in tf.transforms] == c["ids"] == ["cf1"]
        x = np.array([[t.translation.x, t.translation.y, t.translation.z] for t in tf.transforms])
        assert np.allclose(x, np.asarray(c["xvr"]).reshape(-1, 7)[:, :3])
    ball = [e for _, _, sc in fox["/scene"] for e in sc.entities if e.id == "obstacle/ball"]
    assert ball and all(e.spheres[0].size.x == pytest.approx(0.6) for e in ball)
    assert ball[0].spheres[0].pose.position.x == pytest.approx(2.5)
    marks = {e.id for _, _, sc in fox["/scene"] for e in sc.entities if e.id.startswith("collision/")}
    assert len(marks) == len(collisions)
    names = {lg.name for _, _, lg in fox["/log"]}
    assert {"world", "agent-cf1"} <= names
    assert json.loads((crash_run / "foxglove_layout.json").read_text())["content"]["type"] == "split"


def test_message_channels_carry_their_json_schema(crash_run: Path) -> None:
    with open(crash_run / "run.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    by_topic = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    command = by_topic["/agent/cf1/command"]
    assert command.name == "c3swarm.command" and command.encoding == "jsonschema"
    props = json.loads(command.data)["properties"]
    assert {"h_rows", "solve_us", "intervention", "min_h", "status"} <= set(props)
    assert "[us]" in props["solve_us"]["description"]
    assert json.loads(by_topic["/world/clock"].data)["properties"]["xvr"]["type"] == "array"


async def _live_messages(port: int, proc: subprocess.Popen, want: set[str]) -> dict[str, list[bytes]]:
    """Subscribe to ``want`` on the live server until each has sent a message; connect (and
    reconnect, as Foxglove does) while the run is going, at most 120 s."""
    import websockets

    deadline = time.monotonic() + 120
    got: dict[str, list[bytes]] = {}
    schemas: dict[str, bytes] = {}
    while not all(got.get(t) for t in want):
        try:
            async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"]) as ws:
                await _receive(ws, want, got, schemas)
        except (OSError, websockets.ConnectionClosed):  # not up yet, or dropped: again while the run goes
            assert proc.poll() is None and time.monotonic() < deadline, f"the live server gave only {set(got)}"
            await asyncio.sleep(0.05)
    got["_schemas"] = schemas  # type: ignore[assignment]
    return got


async def _receive(ws, want: set[str], got: dict[str, list[bytes]], schemas: dict) -> None:
    channels: dict[int, str] = {}
    while not all(got.get(t) for t in want):
        m = await asyncio.wait_for(ws.recv(), 60)
        if isinstance(m, str):
            j = json.loads(m)
            if j["op"] == "advertise":
                subs = []
                for c in j["channels"]:
                    channels[c["id"]] = c["topic"]
                    schemas[c["topic"]] = (c["schemaName"], c["schema"], c.get("schemaEncoding"))
                    if c["topic"] in want:
                        subs.append({"id": c["id"], "channelId": c["id"]})
                if subs:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        elif m[0] == 1:  # message data: opcode, subscription id (u32), log time (u64), payload
            sub = struct.unpack_from("<I", m, 1)[0]
            got.setdefault(channels[sub], []).append(m[13:])


def test_the_live_server_serves_the_scene_while_the_run_goes(tmp_path: Path) -> None:
    port = free_port("127.0.0.1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "swarm.cli",
            "run",
            str(CONFIGS / "swap_2.yaml"),
            "--out",
            str(tmp_path / "live"),
            "--no-progress",
            "--live",
            str(port),
            "--mode",
            "realtime",
        ],  # realtime: seconds of flight to watch
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        got = asyncio.run(_live_messages(port, proc, {"/scene", "/tf"}))
    finally:
        try:
            out, _ = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            raise
    assert proc.returncode == 0, out[-2000:]
    name, data, encoding = got["_schemas"]["/scene"]
    assert name == "foxglove.SceneUpdate" and encoding == "protobuf"
    decoder = DecoderFactory().decoder_for(
        "protobuf", Schema(id=1, name=name, encoding=encoding, data=base64.b64decode(data))
    )
    ids = {e.id for payload in got["/scene"] for e in decoder(payload).entities}
    assert {"drone/cf1", "drone/cf2"} <= ids
    tf_name, tf_data, _ = got["_schemas"]["/tf"]
    assert tf_name == "foxglove.FrameTransforms"
    tf = DecoderFactory().decoder_for(
        "protobuf", Schema(id=2, name=tf_name, encoding="protobuf", data=base64.b64decode(tf_data))
    )
    assert {t.child_frame_id for t in tf(got["/tf"][0]).transforms} == {"cf1", "cf2"}


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
TRAIL_RGB, OBSTACLE_RGB = (240, 140, 25), (140, 150, 175)


def _pixels(png: bytes, rgb: tuple[int, int, int], tol: int) -> int:
    """Pixels of colour ``rgb`` (+- ``tol``) in the 3-D view (the middle of the window,
    clear of the viewer's panels, whose greys would match too)."""
    from PIL import Image

    im = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    h, w, _ = im.shape
    view = im[int(0.12 * h) : int(0.6 * h), int(0.2 * w) : int(0.75 * w)]
    return int((np.abs(view - np.array(rgb)).max(axis=2) <= tol).sum())


async def _screenshot_when_drawn(debug_port: int, out: Path, proc: subprocess.Popen) -> bytes:
    """Screenshots over the DevTools protocol until the 3-D view shows the trail and the
    sphere (their colours), at most 90 s."""
    import websockets

    deadline = time.monotonic() + 90
    page = None
    while page is None:
        try:
            pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json", timeout=2))
            page = next(p for p in pages if p["type"] == "page")
        except (OSError, StopIteration):
            assert proc.poll() is None and time.monotonic() < deadline, "chromium never opened the page"
            await asyncio.sleep(0.1)
    async with websockets.connect(page["webSocketDebuggerUrl"], max_size=1 << 26) as ws:
        for i in range(1, 10_000):
            await ws.send(json.dumps({"id": i, "method": "Page.captureScreenshot", "params": {"format": "png"}}))
            reply = json.loads(await ws.recv())
            while reply.get("id") != i:
                reply = json.loads(await ws.recv())
            png = base64.b64decode(reply["result"]["data"])
            out.write_bytes(png)
            if _pixels(png, TRAIL_RGB, 30) > 200 and _pixels(png, OBSTACLE_RGB, 40) > 1000:
                return png
            assert time.monotonic() < deadline, f"the scene never showed (last screenshot {out})"
            await asyncio.sleep(0.5)
    raise AssertionError("unreachable")


def test_swarm_view_shows_the_run_in_headless_chromium(crash_run: Path, tmp_path: Path) -> None:
    if CHROMIUM is None:
        if os.environ.get("C3SWARM_CI"):
            pytest.fail("chromium is missing: .ci/run should have installed it")
        pytest.skip("needs Debian's chromium (apt-get install chromium; .ci/run installs it)")
    port, debug_port = free_port("127.0.0.1"), free_port("127.0.0.1")
    view = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "view", str(crash_run), "--port", str(port), "--no-browser"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    browser = None
    try:
        first = view.stdout.readline()  # "serving ...: open URL (Ctrl-C stops)", once the recording is written
        assert "open http://127.0.0.1" in first, first
        url = first.split("open ", 1)[1].split(" ", 1)[0]
        assert (crash_run / "view.rrd").stat().st_size > 0
        seen = []
        for line in view.stdout:  # Rerun's own line once its web server listens (EOF if it dies)
            seen.append(line)
            if "Hosting a web-viewer at" in line:
                break
        else:
            raise AssertionError(f"the web viewer never started: {''.join(seen)[-2000:]}")
        profile = tempfile.mkdtemp(dir=tmp_path)
        browser = subprocess.Popen(
            [
                CHROMIUM,
                "--headless=new",
                "--no-sandbox",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--window-size=1280,800",
                f"--remote-debugging-port={debug_port}",
                f"--user-data-dir={profile}",
                url,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        png = asyncio.run(_screenshot_when_drawn(debug_port, tmp_path / "view.png", browser))
    finally:
        for p in (browser, view):
            if p is not None and p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    colours = Counter(
        map(
            tuple,
            np.asarray(__import__("PIL.Image").Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3).tolist(),
        )
    )
    assert len(colours) > 50  # not a blank or an error page
