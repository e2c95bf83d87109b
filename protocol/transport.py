"""The transport interface, with the Zenoh implementation and an in-memory one.

Parts talk only through `Transport`: publish/subscribe, queries whose reply may
be sent later (the world answers moves once a whole tick is collected), and
liveliness. `ZenohTransport` is the real one; `MemoryTransport` runs the same
code in one process for fast tests.
"""
from __future__ import annotations

import fnmatch
import json
import os
import sys
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable

from .errors import MissionError

# Zenoh runs five Tokio runtimes per session (app, acc, tx, rx, net: six worker threads); every
# message then crosses threads twice more on its way between the socket and Python. For a process
# that handles one robot's few small messages a tick, one runtime of one worker for all of them
# (Zenoh's `handover`) cut the CPU of a lockstep tick of 50 robot processes by a fifth
# (`uav-robots bench ticks`, docs/benchmarks.md). Not for a busy process: the one worker also carries the
# session's sends and keep-alives, so a long callback stalls them (a pool of 250 robots lost its
# session while the UAV's plans came in).
ONE_RUNTIME = "(rx: (handover: app), acc: (handover: app), tx: (handover: app), net: (handover: app))"


def lean_runtime() -> None:
    """One Zenoh runtime for this process's sessions, unless the user set ZENOH_RUNTIME; only
    before the process opens its first session (Zenoh reads the variable then)."""
    os.environ.setdefault("ZENOH_RUNTIME", ONE_RUNTIME)


Callback = Callable[[str, bytes], None]
AliveCallback = Callable[[str, bool], None]


def _report(exc: BaseException, where: str) -> None:
    print(f"warning: {where}: {exc}", file=sys.stderr, flush=True)


def _guard(fn: Callable[..., Any], where: str) -> Callable[..., Any]:
    """Callbacks run on transport threads: an exception there must be one line, never a dead thread."""
    def wrapped(*args: Any) -> None:
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - a bad message must not kill the receiver
            _report(exc, where)
    return wrapped


class IncomingQuery(ABC):
    key: str
    payload: bytes

    @abstractmethod
    def reply(self, payload: bytes) -> None:
        """Send the one reply and finish the query (may be called from any thread, later)."""

    @abstractmethod
    def finish(self) -> None:
        """Finish without a reply (the asker's get() then returns no reply)."""


class Handle:
    def __init__(self, close: Callable[[], None], obj: Any = None) -> None:
        self._close, self.obj = close, obj  # `obj` keeps the declaration alive (pitfall 7)

    def close(self) -> None:
        try:
            self._close()
        except Exception:  # noqa: BLE001 - closing twice or after session close is harmless
            pass


class PendingRequest(ABC):
    @abstractmethod
    def wait(self) -> list[bytes]:
        """The replies that arrived before the request's timeout."""


class Transport(ABC):
    @abstractmethod
    def put(self, key: str, payload: bytes) -> None: ...

    @abstractmethod
    def subscribe(self, key: str, callback: Callback, inline: bool = False) -> Handle:
        """Call `callback(key, payload)` for each sample on `key`. An `inline` callback runs on
        the transport's receiving thread, saving a thread switch per sample (the lockstep's hot
        path); it must return at once and must not wait on the transport."""

    @abstractmethod
    def serve(self, key: str, handler: Callable[[IncomingQuery], None], inline: bool = False) -> Handle:
        """Answer queries on `key`. `inline` handlers run on the transport's receiving thread, so
        the queries of one session reach every inline handler in the order they were sent; they
        must return at once (answer later from elsewhere if the work is long)."""

    @abstractmethod
    def request_start(self, key: str, payload: bytes, timeout: float) -> PendingRequest:
        """Send a query without waiting: a pool of robots asks for all its moves at once."""

    def request(self, key: str, payload: bytes, timeout: float) -> list[bytes]:
        return self.request_start(key, payload, timeout).wait()

    @abstractmethod
    def announce(self, key: str) -> Handle: ...

    @abstractmethod
    def watch_alive(self, key: str, callback: AliveCallback) -> Handle: ...

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> "Transport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------- Zenoh
class _ZenohQuery(IncomingQuery):
    def __init__(self, query: Any) -> None:
        self._q = query
        self.key = str(query.key_expr)
        self.payload = query.payload.to_bytes() if query.payload is not None else b""
        self._lock = threading.Lock()
        self._done = False

    def reply(self, payload: bytes) -> None:
        with self._lock:
            if self._done:
                return
            self._done = True
            try:
                self._q.reply(self._q.key_expr, payload)
            finally:
                self._q.drop()

    def finish(self) -> None:
        with self._lock:
            if not self._done:
                self._done = True
                self._q.drop()


class _ZenohPending(PendingRequest):
    def __init__(self, replies: Any) -> None:
        self._replies = replies

    def wait(self) -> list[bytes]:
        return [r.ok.payload.to_bytes() for r in self._replies if r.ok is not None]


def zenoh_config(config_json5: str, overrides: dict[str, Any] | None = None) -> Any:
    """A zenoh.Config from JSON5 text, with `overrides` ({"connect/endpoints": [...]}) inserted."""
    import zenoh

    try:
        conf = zenoh.Config.from_json5(config_json5)
        for path, value in (overrides or {}).items():
            conf.insert_json5(path, json.dumps(value))
    except Exception as exc:  # noqa: BLE001 - zenoh raises its own ZError
        raise MissionError(f"zenoh config rejected: {str(exc).splitlines()[0]}") from None
    return conf


class ZenohTransport(Transport):
    def __init__(self, config_json5: str, name: str = "session", overrides: dict[str, Any] | None = None) -> None:
        import zenoh

        self._z = zenoh
        conf = zenoh_config(config_json5, overrides)
        try:
            self.session = zenoh.open(conf)
        except Exception as exc:  # noqa: BLE001
            raise MissionError(f"{name}: cannot open zenoh session: {str(exc).splitlines()[0]}") from None
        self.where = "zenoh"      # how the session was opened, for log lines (see open_session)
        self._pubs: dict[str, Any] = {}
        self._queriers: dict[tuple[str, float], Any] = {}
        self._lock = threading.Lock()
        self._handles: list[Handle] = []

    def _publisher(self, key: str) -> Any:
        with self._lock:
            pub = self._pubs.get(key)
            if pub is None:
                pub = self.session.declare_publisher(
                    key, congestion_control=self._z.CongestionControl.BLOCK)
                self._pubs[key] = pub
            return pub

    def put(self, key: str, payload: bytes) -> None:
        self._publisher(key).put(payload)

    def subscribe(self, key: str, callback: Callback, inline: bool = False) -> Handle:
        cb = _guard(callback, f"subscriber {key}")
        sub = self.session.declare_subscriber(key, self._z.handlers.Callback(
            lambda s: cb(str(s.key_expr), s.payload.to_bytes()), indirect=not inline))
        return self._keep(Handle(sub.undeclare, sub))

    def serve(self, key: str, handler: Callable[[IncomingQuery], None], inline: bool = False) -> Handle:
        h = _guard(handler, f"queryable {key}")
        # zenoh-python runs a callback on a thread of its own per queryable unless told otherwise
        # (indirect): then two queryables see one session's queries in no particular order.
        callback = self._z.handlers.Callback(lambda q: h(_ZenohQuery(q)), indirect=not inline)
        qbl = self.session.declare_queryable(key, callback, complete=True)
        return self._keep(Handle(qbl.undeclare, qbl))

    def request_start(self, key: str, payload: bytes, timeout: float) -> PendingRequest:
        # A declared querier per key: a session-level get costs a quarter of a lockstep robot's tick.
        with self._lock:
            querier = self._queriers.get((key, timeout))
            if querier is None:
                querier = self._queriers[(key, timeout)] = self.session.declare_querier(key, timeout=timeout)
        return _ZenohPending(querier.get(payload=payload))

    def announce(self, key: str) -> Handle:
        tok = self.session.liveliness().declare_token(key)
        return self._keep(Handle(tok.undeclare, tok))

    def watch_alive(self, key: str, callback: AliveCallback) -> Handle:
        cb = _guard(callback, f"liveliness {key}")
        put = self._z.SampleKind.PUT
        sub = self.session.liveliness().declare_subscriber(
            key, lambda s: cb(str(s.key_expr), s.kind == put), history=True)
        return self._keep(Handle(sub.undeclare, sub))

    def _keep(self, h: Handle) -> Handle:
        with self._lock:
            self._handles.append(h)
        return h

    def close(self) -> None:
        for h in self._handles:
            h.close()
        self._handles.clear()
        try:
            self.session.close()
        except Exception:  # noqa: BLE001
            pass


# -------------------------------------------------------------------- memory
@dataclass
class MemoryBus:
    """The shared medium of MemoryTransports in one process (a stand-in for a router)."""
    subs: list[tuple[str, Callback]] = field(default_factory=list)
    queryables: list[tuple[str, Callable[[IncomingQuery], None]]] = field(default_factory=list)
    tokens: dict[int, str] = field(default_factory=dict)
    alive_subs: list[tuple[str, AliveCallback]] = field(default_factory=list)
    lock: threading.RLock = field(default_factory=threading.RLock)


def _matches(pattern: str, key: str) -> bool:
    # Zenoh '*' is one chunk, '**' any number; fnmatch's '*' crosses '/', so compare per chunk.
    if "**" in pattern:
        return fnmatch.fnmatchcase(key, pattern.replace("**", "*"))
    p, k = pattern.split("/"), key.split("/")
    return len(p) == len(k) and all(fnmatch.fnmatchcase(kc, pc) for pc, kc in zip(p, k))


class _MemoryQuery(IncomingQuery):
    def __init__(self, key: str, payload: bytes) -> None:
        self.key, self.payload = key, payload
        self.replies: list[bytes] = []
        self.event = threading.Event()

    def reply(self, payload: bytes) -> None:
        if not self.event.is_set():
            self.replies.append(payload)
            self.event.set()

    def finish(self) -> None:
        self.event.set()


class _MemoryPending(PendingRequest):
    def __init__(self, queries: list[_MemoryQuery], deadline: float) -> None:
        self._queries, self._deadline = queries, deadline

    def wait(self) -> list[bytes]:
        out: list[bytes] = []
        for q in self._queries:
            if q.event.wait(max(0.0, self._deadline - time.monotonic())):
                out.extend(q.replies)
        return out


class MemoryTransport(Transport):
    def __init__(self, bus: MemoryBus) -> None:
        self.bus = bus
        self._mine: list[tuple[list[Any], Any]] = []

    def put(self, key: str, payload: bytes) -> None:
        with self.bus.lock:
            targets = [cb for pat, cb in self.bus.subs if _matches(pat, key)]
        for cb in targets:
            cb(key, payload)

    def _add(self, lst: list[Any], item: Any) -> Handle:
        with self.bus.lock:
            lst.append(item)
        self._mine.append((lst, item))

        def close() -> None:
            with self.bus.lock:
                if item in lst:
                    lst.remove(item)
        return Handle(close, item)

    def subscribe(self, key: str, callback: Callback, inline: bool = False) -> Handle:
        return self._add(self.bus.subs, (key, _guard(callback, f"subscriber {key}")))

    def serve(self, key: str, handler: Callable[[IncomingQuery], None], inline: bool = False) -> Handle:
        return self._add(self.bus.queryables, (key, _guard(handler, f"queryable {key}")))

    def request_start(self, key: str, payload: bytes, timeout: float) -> PendingRequest:
        with self.bus.lock:
            targets = [h for pat, h in self.bus.queryables if _matches(key, pat) or _matches(pat, key)]
        queries = []
        for h in targets:
            q = _MemoryQuery(key, payload)
            h(q)
            queries.append(q)
        return _MemoryPending(queries, time.monotonic() + timeout)

    def announce(self, key: str) -> Handle:
        token = object()
        with self.bus.lock:
            self.bus.tokens[id(token)] = key
            watchers = [cb for pat, cb in self.bus.alive_subs if _matches(pat, key)]
        for cb in watchers:
            cb(key, True)

        def close() -> None:
            with self.bus.lock:
                gone = self.bus.tokens.pop(id(token), None)
                ws = [cb for pat, cb in self.bus.alive_subs if gone and _matches(pat, gone)]
            for cb in ws:
                cb(key, False)
        h = Handle(close, token)
        self._mine.append(([], h))
        return h

    def watch_alive(self, key: str, callback: AliveCallback) -> Handle:
        cb = _guard(callback, f"liveliness {key}")
        with self.bus.lock:
            present = [k for k in self.bus.tokens.values() if _matches(key, k)]
        h = self._add(self.bus.alive_subs, (key, cb))
        for k in present:
            cb(k, True)
        return h

    def close(self) -> None:
        for lst, item in reversed(self._mine):
            if isinstance(item, Handle):
                item.close()
            else:
                with self.bus.lock:
                    if item in lst:
                        lst.remove(item)
        self._mine.clear()


SAY_WAITING_AFTER_S = 2.0


def open_session(name: str, listen: list[str] | None = None, connect: list[str] | None = None,
                 config_file: str | None = None, stop: threading.Event | None = None,
                 alone: str = "client", wait_s: float = 20.0) -> ZenohTransport:
    """The Zenoh session of one process, opened so that a signal is answered within about a second.

    A config file or `listen` is opened as given (`listen`/`connect` then replace the file's endpoints;
    a client config is retried like `connect`). `connect` is retried in 1 s attempts for up to
    `wait_s` (a router may come up later), stopping early when `stop` is set. With none of them the
    process is on its own, as a simulator started alone: `alone="client"` joins the router on this
    machine, `"router"` becomes it, `"either"` joins one if it answers within a second, else becomes it.
    """
    from .config import DEFAULT_ENDPOINT, client_config, config_from_file, hub_config

    def opened(config: str, where: str, overrides: dict[str, Any] | None = None) -> ZenohTransport:
        t = ZenohTransport(config, name, overrides)
        t.where = where
        return t

    def retried(attempt: Callable[[], ZenohTransport], endpoints: list[str], wait: float,
                otherwise: Callable[[], ZenohTransport] | None = None) -> ZenohTransport:
        start = time.monotonic()
        deadline = start + wait
        said = otherwise is not None   # "either" is about to become the router: nothing to wait for
        while True:
            try:
                return attempt()
            except MissionError:
                # A long silent wait looks like a hang; a short one is a router still starting.
                if not said and time.monotonic() - start >= SAY_WAITING_AFTER_S:
                    print(f"{name}: waiting up to {wait:g} s for a Zenoh router at {', '.join(endpoints)}",
                          file=sys.stderr, flush=True)
                    said = True
                if stop is not None and stop.is_set():
                    raise MissionError(f"{name}: stopped while waiting for a Zenoh router") from None
                if time.monotonic() >= deadline:
                    if otherwise is not None:
                        return otherwise()
                    raise MissionError(f"{name}: no Zenoh router at {', '.join(endpoints)} within {wait:g} s") from None

    if config_file:
        text = config_from_file(config_file)
        over: dict[str, Any] = {**({"listen/endpoints": listen} if listen else {}),
                                **({"connect/endpoints": connect} if connect else {})}
        where = f"config {config_file}"
        if json.loads(zenoh_config(text).get_json("mode") or "null") != "client":
            return opened(text, where, over)
        # A client retries in short attempts, as with --connect, so that a signal is answered meanwhile.
        endpoints = connect or json.loads(zenoh_config(text).get_json("connect/endpoints") or "[]")
        return retried(lambda: opened(text, where, {**over, "connect/timeout_ms": 1000}), endpoints, wait_s)
    if listen or (not connect and alone == "router"):
        endpoints = listen or [DEFAULT_ENDPOINT]
        return opened(hub_config(endpoints), f"listening on {', '.join(endpoints)}")
    endpoints = connect or [DEFAULT_ENDPOINT]
    if not connect and alone == "either":
        return retried(lambda: opened(client_config(endpoints, timeout_ms=1000), f"connected to {DEFAULT_ENDPOINT}"),
                       endpoints, 1.0, lambda: opened(hub_config([DEFAULT_ENDPOINT]),
                                                      f"listening on {DEFAULT_ENDPOINT} (no router found)"))
    return retried(lambda: opened(client_config(endpoints, timeout_ms=1000), f"connected to {', '.join(endpoints)}"),
                   endpoints, wait_s)
