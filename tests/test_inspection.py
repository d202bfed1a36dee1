"""Remote inspection safe to expose (issue 12 part 1): loopback by default, CURVE keys for
anything else, bounded whatever clients send, request/reply, run start/end with a run id."""
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import zmq

from actors.inspection import (
    InspectionServer, check_inspection, inspection_client, inspection_request, load_client_keys, load_server_keys,
    request_endpoint,
)
from protocol.codec import encode
from protocol.messages import FrameDone, InspectRequest, RunEnd, RunStart
from shared.errors import ConfigError
from tools.make_inspect_keys import make_keys

ROOT = Path(__file__).resolve().parents[1]


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _answer(command):
    return ({"frames_done": 3}, None) if command == "status" else ({}, f"{command!r} is not available")


def _pump(server, seconds, until=lambda: False):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not until():
        server.serve(_answer, "run-x")
        time.sleep(0.01)


def _publish_for(server, seconds, sockets):
    """Publish frame_done events while serving, until every socket has something or time is up."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not all(s.poll(0) for s in sockets):
        server.serve(_answer, "run-x")
        server.publish("frame_done", encode(FrameDone(index=1)))
        time.sleep(0.02)


@pytest.fixture
def server(tmp_path):
    zctx = zmq.Context()
    srv = InspectionServer(zctx, f"ipc://{tmp_path}/insp")
    yield srv, f"ipc://{tmp_path}/insp", zctx
    srv.close()
    zctx.term()


ATTACKER = """
import sys, time, zmq, numpy as np
ctx = zmq.Context.instance()
endpoint = sys.argv[1]
huge = ctx.socket(zmq.SUB)                    # a 20 MB subscription prefix (grew the launcher to 2.4 GB)
huge.setsockopt(zmq.SUBSCRIBE, b"x" * (20 << 20))
huge.connect(endpoint)
junk = ctx.socket(zmq.SUB)                    # 2000 random prefixes and a prefix of a kind
for k in range(2000):
    junk.setsockopt(zmq.SUBSCRIBE, np.random.default_rng(k).bytes(200))
junk.setsockopt(zmq.SUBSCRIBE, b"fra")
junk.connect(endpoint)
req = ctx.socket(zmq.DEALER)                  # 10 000 random messages on the request socket
req.setsockopt(zmq.SNDTIMEO, 5000)            # the server reads while we send; never wait forever
req.connect(endpoint + ".req")
rng = np.random.default_rng(0)
for k in range(10_000):
    req.send(rng.bytes(int(rng.integers(0, 300))))
t = time.time()
got = 0
while time.time() - t < float(sys.argv[2]):
    got += bool(junk.poll(50)) and len(junk.recv_multipart()) > 0
print(got)
"""


def test_hostile_clients_do_not_grow_the_launcher_and_get_nothing(server):
    srv, endpoint, _ = server
    rss_before = psutil.Process().memory_info().rss
    attacker = subprocess.Popen([sys.executable, "-c", ATTACKER, endpoint, "4"], stdout=subprocess.PIPE, text=True)
    good = zmq.Context.instance().socket(zmq.SUB)
    good.setsockopt(zmq.SUBSCRIBE, b"frame_done")
    good.connect(endpoint)
    try:
        deadline = time.monotonic() + 60
        while attacker.poll() is None and time.monotonic() < deadline:
            srv.serve(_answer, "run-x")
            srv.publish("frame_done", encode(FrameDone(index=1)))
            time.sleep(0.005)
        junk_received = int(attacker.communicate(timeout=30)[0].strip() or -1)
    finally:
        if attacker.poll() is None:
            attacker.kill()
    assert good.poll(0), "a subscriber to a known kind got nothing"
    assert junk_received == 0, "a subscription that is not a message kind received events"
    grown_mb = (psutil.Process().memory_info().rss - rss_before) / 2**20
    assert grown_mb < 50, f"the launcher side grew {grown_mb:.0f} MB"  # nothing the clients sent is kept
    good.close(linger=0)


def test_requests_are_answered_and_bad_ones_refused(server):
    srv, endpoint, _ = server
    ctx = zmq.Context.instance()
    dealer = ctx.socket(zmq.DEALER)
    dealer.connect(request_endpoint(endpoint))

    def ask(payload):
        dealer.send(payload)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and not dealer.poll(0):
            srv.serve(_answer, "run-x")
            time.sleep(0.01)
        from protocol.codec import decode
        return decode(dealer.recv()) if dealer.poll(0) else None

    ok = ask(encode(InspectRequest(command="status", request_id=7)))
    assert ok.ok and ok.request_id == 7 and ok.run_id == "run-x" and ok.payload == {"frames_done": 3}
    garbage = ask(b"\xc1\x00garbage")
    assert not garbage.ok and "undecodable" in garbage.error
    unknown = ask(encode(InspectRequest(command="format-disk")))
    assert not unknown.ok and "unknown command" in unknown.error
    wrong = ask(encode(FrameDone(index=1)))
    assert not wrong.ok and "expected an inspect_request" in wrong.error
    dealer.close(linger=0)
    # An oversized request drops that client's connection; other clients are still served.
    big = ctx.socket(zmq.DEALER)
    big.connect(request_endpoint(endpoint))
    big.send(b"\x00" * 100_000)
    _pump(srv, 0.5)
    assert not big.poll(0)
    big.close(linger=0)
    dealer = ctx.socket(zmq.DEALER)
    dealer.connect(request_endpoint(endpoint))
    assert ask(encode(InspectRequest(command="status"))).ok
    dealer.close(linger=0)


def test_curve_keys_let_the_authorised_client_in_and_no_one_else(tmp_path):
    keys = make_keys(tmp_path / "keys", ["laptop"])
    other = make_keys(tmp_path / "other", ["intruder"])
    endpoint = f"tcp://127.0.0.1:{_port()}"
    zctx = zmq.Context()
    srv = InspectionServer(zctx, endpoint, load_server_keys(tmp_path / "keys"))
    server_public = tmp_path / "keys" / "server.key"
    try:
        ctx = zmq.Context.instance()
        subs = {}
        for name, secret in (("laptop", keys["laptop"]), ("intruder", other["intruder"])):
            ck = load_client_keys(secret, server_public)
            s = ctx.socket(zmq.SUB)
            s.curve_secretkey, s.curve_publickey, s.curve_serverkey = ck.secret, ck.public, ck.server_public
            s.setsockopt(zmq.SUBSCRIBE, b"")
            s.connect(endpoint)
            subs[name] = s
        _pump(srv, 1.0)
        _publish_for(srv, 5.0, [subs["laptop"]])
        assert subs["laptop"].poll(0), "the authorised client got no events"
        assert not subs["intruder"].poll(0), "a client with another key got events"
        # requests, through the client helper, answered from a thread-free pump
        import threading
        stop = threading.Event()
        pump = threading.Thread(target=lambda: _pump(srv, 10, stop.is_set))
        pump.start()
        try:
            reply = inspection_request(endpoint, "status", timeout_s=5,
                                       keys=load_client_keys(keys["laptop"], server_public))
            refused = inspection_request(endpoint, "status", timeout_s=1.5,
                                         keys=load_client_keys(other["intruder"], server_public))
        finally:
            stop.set()
            pump.join()
        assert reply is not None and reply.ok and reply.payload["frames_done"] == 3
        assert refused is None
        for s in subs.values():
            s.close(linger=0)
    finally:
        srv.close()
        zctx.term()


def test_non_loopback_needs_keys(tmp_path):
    with pytest.raises(ConfigError, match="needs CURVE keys"):
        check_inspection(f"tcp://0.0.0.0:{_port()}", None)
    make_keys(tmp_path / "keys", ["c"])
    assert check_inspection(f"tcp://0.0.0.0:{_port()}", str(tmp_path / "keys")) is not None
    assert check_inspection(f"tcp://127.0.0.1:{_port()}", None) is None
    assert check_inspection(f"ipc://{tmp_path}/x", None) is None


def test_a_run_announces_itself_answers_status_and_stops_on_request(tmp_path):
    endpoint = f"ipc://{tmp_path}/inspect"
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, str(ROOT / "launch.py"), "--dataset", "euroc", "--out", str(out),
                             "--inspect", endpoint, "--quiet"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        start, end, status, stop = None, None, None, None
        for msg in inspection_client(endpoint, ["run_start", "pose"], timeout_s=120, until_run_end=True):
            if isinstance(msg, RunStart):
                start = msg
            elif isinstance(msg, RunEnd):
                end = msg
            elif msg.index >= 10 and stop is None:
                status = inspection_request(endpoint, "status", timeout_s=30)
                stop = inspection_request(endpoint, "stop", timeout_s=30)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert status is not None and status.ok and status.payload["frames_done"] >= 10
    assert set(status.payload["actors"]) == {"source", "enhancement", "tracking", "local_mapping", "loop_closing"}
    assert stop is not None and stop.ok
    assert end is not None and end.reason == "stopped by a remote client" and not end.ok
    assert end.run_id == status.run_id
    if start is not None:  # a subscriber may join after run_start; status carries the run id too
        assert start.run_id == end.run_id and start.n_frames == 95
    assert proc.returncode == 1 and "stopped by a remote client" in stderr and "Traceback" not in stderr
    assert len(np.loadtxt(out / "trajectory.tum")) >= 10


def test_watcher_names_the_run_and_exits_at_its_end(tmp_path):
    endpoint = f"ipc://{tmp_path}/inspect"
    launcher = subprocess.Popen([sys.executable, str(ROOT / "launch.py"), "--dataset", "euroc", "--max-frames", "15",
                                 "--out", str(tmp_path / "run"), "--inspect", endpoint, "--quiet"], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        watcher = subprocess.run([sys.executable, str(ROOT / "tools" / "watch_run.py"), endpoint, "--timeout", "120"],
                                 cwd=ROOT, capture_output=True, text=True, timeout=300)
        launcher.communicate(timeout=120)
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.communicate()
    assert launcher.returncode == 0
    assert watcher.returncode == 0, watcher.stderr[-2000:]
    lines = watcher.stdout.splitlines()
    assert lines[0].startswith("run   euroc-"), lines[:3]  # the run id, from status or run_start
    run_id = lines[0].split()[1]
    assert lines[-1].startswith(f"end   {run_id}  completed"), lines[-3:]
    assert sum(ln.startswith("pose") for ln in lines) >= 1


def test_hostile_clients_do_not_change_a_lockstep_run(tmp_path):
    """Clients flooding every inspection socket neither change the lockstep trajectory nor break the run."""
    trajs = []
    for k, attacked in enumerate((False, True)):
        endpoint = f"ipc://{tmp_path}/inspect{k}"
        out = tmp_path / f"run{k}"
        launcher = subprocess.Popen([sys.executable, str(ROOT / "launch.py"), "--dataset", "kitti", "--max-frames",
                                     "8", "--out", str(out), "--quiet"] + (["--inspect", endpoint] if attacked else []),
                                    cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        attacker = None
        if attacked:
            attacker = subprocess.Popen([sys.executable, "-c", ATTACKER, endpoint, "6"], stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True)
        try:
            _, stderr = launcher.communicate(timeout=300)
            if attacker is not None:
                attacker.communicate(timeout=60)
        finally:
            for p in (launcher, attacker):
                if p is not None and p.poll() is None:
                    p.kill()
                    p.communicate()
        assert launcher.returncode == 0, stderr[-2000:]
        trajs.append((out / "trajectory.tum").read_text())
    assert trajs[0] == trajs[1]
