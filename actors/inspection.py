"""The launcher's inspection endpoint: a publish stream and a request/reply channel, safe to expose.

- **Publish stream** (ZeroMQ XPUB at ``--inspect ENDPOINT``): every actor event as multipart
  ``[kind, payload]``, framed by ``run_start`` / ``run_end`` events that carry the run id.
  Whole-map snapshots go out as ``map_delta`` (new / moved / removed points) and downscaled
  JPEG frames (``inspect_frame``) only to clients that ask for them: see
  ``actors.inspection_stream``.
- **Requests** (ROUTER at ``request_endpoint(ENDPOINT)``: the next TCP port, or ``<path>.req``
  for ipc): an ``InspectRequest`` (status, config, stats, map, pause, resume, save_map, stop)
  gets an ``InspectReply``.

Safety (issue 12):
- Loopback (127.0.0.0/8, ::1, ipc://) binds with no keys. Any other address needs ZeroMQ CURVE
  keys (``--inspect-keys DIR`` made by ``tools/make_inspect_keys.py``): the server key pair and
  the public keys of allowed clients; without them the launcher refuses to start. A client
  whose key is not allowed is refused by the ZAP handshake and receives nothing.
- Bounded whatever clients send: incoming messages over ``MAX_CLIENT_MESSAGE_BYTES`` make
  ZeroMQ drop the connection before the message is stored (``ZMQ_MAXMSGSIZE``); subscriptions
  are handled by hand (``XPUB_MANUAL``) and only the known message kinds are ever subscribed, so
  a client cannot grow the subscription trie; per-client send queues are capped
  (``SNDHWM``: a slow client loses messages, the launcher does not buffer them); at most
  ``MAX_REQUESTS_PER_POLL`` requests are served per supervisor loop turn; at most
  ``MAX_CLIENTS`` connections per socket (subscribers; request clients): the ZAP handshake
  (run for every connection, keys or not) refuses the next one until a client leaves.
"""
from __future__ import annotations

import ipaddress
import re
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import zmq

from actors.inspection_stream import InspectStream
from protocol.codec import decode, encode, registered_kinds
from protocol.messages import InspectFrame, InspectReply, InspectRequest
from shared.errors import ConfigError, ProtocolError

MAX_CLIENT_MESSAGE_BYTES = 4096     # a subscription or request is a few dozen bytes
PUBLISH_HWM = 100                   # messages queued per subscriber before it loses some
REPLY_HWM = 100
MAX_REQUESTS_PER_POLL = 20
MAX_CLIENTS = 32                    # open connections per socket; the load test uses 20 subscribers
SERVER_SECRET = "server.key_secret"
SERVER_PUBLIC = "server.key"
AUTHORIZED_DIR = "authorized"       # public keys (*.key) of allowed clients
COMMANDS = ("status", "config", "stats", "map", "pause", "resume", "save_map", "stop")


@dataclass(frozen=True)
class Endpoint:
    text: str
    scheme: str          # "tcp" | "ipc"
    host: str = ""
    port: int = 0

    @property
    def loopback(self) -> bool:
        return self.scheme == "ipc" or _is_loopback_host(self.host)


def parse_endpoint(text: str, where: str = "--inspect") -> Endpoint:
    """``tcp://HOST:PORT`` or ``ipc://PATH``; ConfigError naming the input otherwise."""
    where = f"{where} {text}"
    m = re.fullmatch(r"(tcp|ipc)://(.+)", text or "")
    if m is None:
        raise ConfigError(where, "expected tcp://HOST:PORT or ipc://PATH")
    if m.group(1) == "ipc":
        return Endpoint(text, "ipc")
    host, sep, port = m.group(2).rpartition(":")
    if not sep or not host or not (port.isdigit() and 1 <= int(port) <= 65534):
        raise ConfigError(where, "expected tcp://HOST:PORT with a port number 1..65534 (the next port "
                                 "serves requests)")
    if host not in ("*", "0.0.0.0"):
        try:
            socket.getaddrinfo(host.strip("[]"), None)
        except (socket.gaierror, UnicodeError):
            raise ConfigError(where, f"unknown host {host!r}") from None
    return Endpoint(text, "tcp", host, int(port))


def _is_loopback_host(host: str) -> bool:
    host = host.strip("[]")
    if host in ("*", "0.0.0.0", "::"):
        return False
    try:
        addrs = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except (socket.gaierror, UnicodeError):
        return False
    return bool(addrs) and all(ipaddress.ip_address(a.split("%")[0]).is_loopback for a in addrs)


def request_endpoint(endpoint: str) -> str:
    """The request/reply endpoint that goes with a publish endpoint."""
    ep = parse_endpoint(endpoint)
    if ep.scheme == "ipc":
        return f"{endpoint}.req"
    return f"tcp://{ep.host}:{ep.port + 1}"


@dataclass(frozen=True)
class ServerKeys:
    public: bytes
    secret: bytes
    authorized_dir: Path


def load_server_keys(folder: str | Path) -> ServerKeys:
    """The server key pair and the allowed clients' folder made by tools/make_inspect_keys.py."""
    import zmq.auth

    folder = Path(folder)
    where = f"--inspect-keys {folder}"
    secret_file = folder / SERVER_SECRET
    if not secret_file.is_file():
        raise ConfigError(where, f"no {SERVER_SECRET} (make the keys with tools/make_inspect_keys.py)")
    try:
        public, secret = zmq.auth.load_certificate(secret_file)
    except (ValueError, OSError) as exc:
        raise ConfigError(secret_file, f"not a CURVE secret key file ({exc})") from None
    if secret is None:
        raise ConfigError(secret_file, "holds no secret key")
    authorized = folder / AUTHORIZED_DIR
    if not authorized.is_dir() or not any(authorized.glob("*.key")):
        raise ConfigError(where, f"no allowed client keys in {AUTHORIZED_DIR}/ (*.key)")
    return ServerKeys(public, secret, authorized)


def check_inspection(endpoint: str, keys_dir: str | None) -> ServerKeys | None:
    """Validate ``--inspect`` before any process starts: syntax, host, loopback-or-keys, and that
    both endpoints can be bound now (a port in use fails here with one line)."""
    ep = parse_endpoint(endpoint)
    keys = load_server_keys(keys_dir) if keys_dir else None
    if not ep.loopback and keys is None:
        raise ConfigError(f"--inspect {endpoint}", "a non-loopback address needs CURVE keys: make them with "
                                                   "tools/make_inspect_keys.py DIR and pass --inspect-keys DIR "
                                                   "(or bind tcp://127.0.0.1:PORT)")
    zctx = zmq.Context.instance()
    for what in (endpoint, request_endpoint(endpoint)):
        probe = zctx.socket(zmq.PUB)
        try:
            probe.bind(what)
        except zmq.ZMQError as exc:
            raise ConfigError(f"--inspect {endpoint}", f"cannot listen on {what}: {exc}") from None
        finally:
            probe.close(linger=0)
    return keys


class _OpenConnections:
    """Open connections of one socket, from its monitor. Used by the ZAP thread alone (the only
    reader of the monitor socket), when it decides on a new connection."""

    ACCEPT_WAIT_S = 0.2

    def __init__(self, sock: zmq.Socket, cap: int):
        self.monitor = sock.get_monitor_socket(zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED)
        self.cap = cap
        self.open: set[int] = set()
        self.asked = 0       # ZAP requests for this socket so far
        self.accepted = 0    # ACCEPTED events seen so far

    def count(self) -> int:
        """Open connections, the one being decided included: every ZAP request follows an accept,
        so wait (briefly) until as many accepts as requests were seen."""
        from zmq.utils.monitor import recv_monitor_message

        deadline = time.monotonic() + self.ACCEPT_WAIT_S
        while True:
            wait_ms = 0 if self.accepted >= self.asked else max(0, int((deadline - time.monotonic()) * 1e3))
            if not self.monitor.poll(wait_ms):
                return len(self.open)
            event = recv_monitor_message(self.monitor)
            if event["event"] == zmq.EVENT_ACCEPTED:
                self.accepted += 1
                self.open.add(event["value"])
            else:
                self.open.discard(event["value"])


def _capped_authenticator(zctx: zmq.Context, limits: dict[bytes, _OpenConnections]):
    """pyzmq's ZAP handler (CURVE keys when configured, NULL allowed otherwise) that also refuses a
    connection when its socket already has ``cap`` open ones."""
    from zmq.auth.thread import ThreadAuthenticator

    class CappedAuthenticator(ThreadAuthenticator):
        domain = b""

        async def handle_zap_message(self, msg: list[bytes]) -> None:
            self.domain = msg[2] if len(msg) > 2 else b""
            if self.domain in limits:
                limits[self.domain].asked += 1
            await super().handle_zap_message(msg)

        def _send_zap_reply(self, request_id, status_code, status_text, user_id="anonymous") -> None:
            limit = limits.get(self.domain)
            if status_code == b"200" and limit is not None and limit.count() > limit.cap:
                status_code, status_text = b"400", b"too many clients"
            super()._send_zap_reply(request_id, status_code, status_text, user_id)

    return CappedAuthenticator(zctx)


class InspectionServer:
    """Owned by the supervisor; ``publish`` events, ``serve`` requests once per loop turn."""

    def __init__(self, zctx: zmq.Context, endpoint: str, keys: ServerKeys | None = None, frames=None,
                 max_clients: int = MAX_CLIENTS):
        self.endpoint = endpoint
        self.stream = InspectStream(frames)
        self.auth = None
        self.pub = zctx.socket(zmq.XPUB)
        self.rep = zctx.socket(zmq.ROUTER)
        self._allowed = {k.encode() for k in registered_kinds()} | {b""}
        self._limits: dict[bytes, _OpenConnections] = {}
        try:
            for sock, domain in ((self.pub, b"canopy.inspect.pub"), (self.rep, b"canopy.inspect.req")):
                sock.zap_domain = domain  # makes ZMQ ask the ZAP handler about every connection
                self._limits[domain] = _OpenConnections(sock, max_clients)
            self.auth = _capped_authenticator(zctx, self._limits)
            self.auth.start()
            if keys is not None:  # pyzmq looks keys up by ZAP domain ("*" only stands for "")
                for domain in self._limits:
                    self.auth.configure_curve(domain=domain.decode(), location=str(keys.authorized_dir))
            for sock, hwm in ((self.pub, PUBLISH_HWM), (self.rep, REPLY_HWM)):
                sock.setsockopt(zmq.MAXMSGSIZE, MAX_CLIENT_MESSAGE_BYTES)
                sock.setsockopt(zmq.SNDHWM, hwm)
                sock.setsockopt(zmq.RCVHWM, hwm)
                sock.setsockopt(zmq.LINGER, 500)
                if keys is not None:
                    sock.curve_secretkey = keys.secret
                    sock.curve_publickey = keys.public
                    sock.curve_server = True
            self.pub.setsockopt(zmq.XPUB_MANUAL, 1)
            self.pub.bind(endpoint)
            self.rep.bind(request_endpoint(endpoint))
        except zmq.ZMQError as exc:
            self.close()
            raise ConfigError(f"--inspect {endpoint}", f"cannot listen there: {exc}") from None

    def publish(self, kind: str, payload: bytes) -> None:
        try:
            self.pub.send_multipart([kind.encode(), payload], zmq.NOBLOCK)
        except zmq.Again:
            pass  # every subscriber's queue is full: it loses this event, the run goes on

    def publish_event(self, msg: Any, payload: bytes) -> None:
        """An actor event as the stream shows it (map snapshots as deltas, frames on request)."""
        try:
            out = list(self.stream.events(msg, payload))
        except Exception:  # a preview or delta that fails must never end the run: send the event as is
            out = [(msg.KIND, payload)]
        for kind, body in out:
            self.publish(kind, body)

    def serve(self, handler: Callable[[str], tuple[dict, str | None]], run_id: str) -> None:
        """Apply pending subscriptions and answer up to MAX_REQUESTS_PER_POLL requests.
        ``handler(command)`` returns (payload, error or None)."""
        while self.pub.poll(0):
            frame = self.pub.recv()
            if len(frame) >= 1 and frame[0] in (0, 1):
                topic = frame[1:]
                if topic in self._allowed:  # anything else is never added to the subscription trie
                    self.pub.setsockopt(zmq.SUBSCRIBE if frame[0] == 1 else zmq.UNSUBSCRIBE, topic)
                    if frame[0] == 1 and topic == InspectFrame.KIND.encode():
                        self.stream.frames_wanted = True  # encode JPEGs from now on (rate-capped)
        for _ in range(MAX_REQUESTS_PER_POLL):
            if not self.rep.poll(0):
                break
            frames = self.rep.recv_multipart()
            if len(frames) == 3 and frames[1] == b"":       # REQ client: identity, delimiter, body
                route, body = frames[:2], frames[2]
            elif len(frames) == 2:                            # DEALER client: identity, body
                route, body = frames[:1], frames[1]
            else:
                continue  # not a request: dropped
            self._answer(route, body, handler, run_id)

    def _answer(self, route: list[bytes], body: bytes, handler, run_id: str) -> None:
        request_id = 0
        try:
            req = decode(body)
            if not isinstance(req, InspectRequest):
                raise ProtocolError(f"expected an inspect_request, got {req.KIND}")
            request_id = req.request_id
            if req.command not in COMMANDS:
                raise ProtocolError(f"unknown command {req.command!r}; one of {', '.join(COMMANDS)}")
            payload, error = handler(req.command)
            reply = InspectReply(request_id=request_id, ok=error is None, run_id=run_id, payload=payload,
                                 error=error or "")
        except ProtocolError as exc:
            reply = InspectReply(request_id=request_id, ok=False, run_id=run_id, error=str(exc))
        try:
            self.rep.send_multipart([*route, encode(reply)], zmq.NOBLOCK)
        except (zmq.Again, zmq.ZMQError):
            pass  # the client is gone or not reading

    def close(self) -> None:
        for sock in (self.pub, self.rep):
            sock.close(linger=500)
        if self.auth is not None:
            self.auth.stop()
            self.auth = None
        for limit in self._limits.values():  # after the ZAP thread, the only user of the monitors
            limit.monitor.close(linger=0)
        self._limits = {}


# -- clients ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ClientKeys:
    public: bytes
    secret: bytes
    server_public: bytes


def load_client_keys(client_secret_file: str | Path, server_public_file: str | Path) -> ClientKeys:
    import zmq.auth

    public, secret = zmq.auth.load_certificate(client_secret_file)
    server_public, _ = zmq.auth.load_certificate(server_public_file)
    if secret is None:
        raise ConfigError(client_secret_file, "holds no secret key")
    return ClientKeys(public, secret, server_public)


def _client_socket(kind: int, endpoint: str, keys: ClientKeys | None) -> zmq.Socket:
    sock = zmq.Context.instance().socket(kind)
    if keys is not None:
        sock.curve_secretkey = keys.secret
        sock.curve_publickey = keys.public
        sock.curve_serverkey = keys.server_public
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(endpoint)
    return sock


def inspection_client(endpoint: str, kinds: list[str] | None = None, timeout_s: float = 10.0,
                      keys: ClientKeys | None = None, until_run_end: bool = False):
    """Yield messages from a running launcher's inspection stream until ``timeout_s`` of silence
    (or, with ``until_run_end``, until its ``run_end`` event, which is yielded last)."""
    sub = _client_socket(zmq.SUB, endpoint, keys)
    for kind in (kinds or [""]):
        sub.setsockopt(zmq.SUBSCRIBE, kind.encode())
    if until_run_end and kinds:
        sub.setsockopt(zmq.SUBSCRIBE, b"run_end")
    try:
        while sub.poll(int(timeout_s * 1000)):
            _, payload = sub.recv_multipart()
            msg = decode(payload)
            yield msg
            if until_run_end and msg.KIND == "run_end":
                return
    finally:
        sub.close(linger=0)


def inspection_request(endpoint: str, command: str, timeout_s: float = 5.0, keys: ClientKeys | None = None,
                       request_id: int = 1) -> InspectReply | None:
    """Send one request to a launcher's request endpoint; the reply, or None on timeout."""
    sock = _client_socket(zmq.DEALER, request_endpoint(endpoint), keys)
    try:
        sock.send(encode(InspectRequest(command=command, request_id=request_id)))
        if not sock.poll(int(timeout_s * 1000)):
            return None
        reply: Any = decode(sock.recv())
        return reply if isinstance(reply, InspectReply) else None
    finally:
        sock.close(linger=0)
