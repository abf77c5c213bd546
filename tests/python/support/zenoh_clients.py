"""The Python side of the wire: Zenoh sessions that reach armtwin, what they receive, what they ask.

Written against docs/protocol/ (the wire contract), not the Rust source.

* :func:`open_session` is a peer of one armtwin's listener; :func:`open_client` a client of a
  router (TLS if asked).
* :class:`Collector` records every output sample (``twin/**`` minus the input subtrees) in a
  thread-safe list from the Zenoh callback; JSON is decoded later, off the receive thread.
* :class:`TwinClient` is one Python Zenoh peer: it declares the output subscriber, per-robot input
  publishers (congestion control BLOCK, remote destinations only) and waits until armtwin's
  subscribers and queryables are matched and armtwin has seen the subscriber (a query round trip).
* :class:`Poses` is a dashboard's subscriber of one robot's poses; :func:`get_json`,
  :func:`paired_of`, :func:`wait_queryable` and :func:`wait_matched` are bounded queries and waits.

Every wait here is bounded.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field

import zenoh

from support.process import bounded_endpoint, wait_until

PREFIX = "twin"
INPUT_STREAMS = ("joints", "measured")
OUTPUT_STREAMS = ("pose", "deviation", "metrics", "events")

MATCH_TIMEOUT_S = 15.0
QUERY_TIMEOUT_S = 10.0
def open_session(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([bounded_endpoint(endpoint)]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@dataclass
class Received:
    at: float  # time.monotonic() at reception
    key: str
    payload: bytes
    _json: object = field(default=None, repr=False)

    @property
    def stream(self) -> str:
        return self.key.split("/", 2)[1]

    @property
    def robot(self) -> str:
        return self.key.split("/", 2)[2]

    def json(self):
        if self._json is None:
            self._json = json.loads(self.payload)
        return self._json


class Collector:
    """Thread-safe record of output samples, in arrival order."""

    def __init__(self):
        self._lock = threading.Lock()
        self._items: list[Received] = []
        self._counts: dict[tuple[str, str], int] = {}
        self.ignored_inputs = 0

    def __call__(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/", 2)
        if len(parts) < 3 or parts[1] in INPUT_STREAMS:
            with self._lock:
                self.ignored_inputs += 1
            return
        item = Received(time.monotonic(), key, sample.payload.to_bytes())
        with self._lock:
            self._items.append(item)
            k = (parts[1], parts[2])
            self._counts[k] = self._counts.get(k, 0) + 1

    def count(self, stream: str, robot: str) -> int:
        with self._lock:
            return self._counts.get((stream, robot), 0)

    def items(self, stream: str | None = None, robot: str | None = None) -> list[Received]:
        with self._lock:
            items = list(self._items)
        return [
            i
            for i in items
            if (stream is None or i.stream == stream) and (robot is None or i.robot == robot)
        ]

    def messages(self, stream: str, robot: str) -> list[dict]:
        return [i.json() for i in self.items(stream, robot)]

    def last(self, stream: str, robot: str) -> dict | None:
        items = self.items(stream, robot)
        return items[-1].json() if items else None

    def wait_count(self, stream: str, robot: str, n: int, timeout: float) -> bool:
        return wait_until(lambda: self.count(stream, robot) >= n, timeout)

    def wait_message(self, stream: str, robot: str, predicate, timeout: float) -> dict | None:
        """The first message on ``stream``/``robot`` satisfying ``predicate``, polled until
        ``timeout``; None if none."""
        seen = 0
        deadline = time.monotonic() + timeout
        while True:
            items = self.items(stream, robot)
            for item in items[seen:]:
                msg = item.json()
                if predicate(msg):
                    return msg
            seen = len(items)
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.02)


def reply_payloads(replies) -> tuple[list[tuple[str, dict]], list[dict]]:
    """Split replies into ([(key, ok json)], [error json])."""
    oks, errs = [], []
    for reply in replies:
        if reply.ok is not None:
            oks.append((str(reply.ok.key_expr), json.loads(reply.ok.payload.to_bytes())))
        else:
            raw = reply.err.payload.to_bytes()
            try:
                errs.append(json.loads(raw))
            except ValueError:
                errs.append({"<raw>": raw.decode(errors="replace")})
    return oks, errs


class EncodingCollector(Collector):
    """A Collector that also records each output stream's encodings."""

    def __init__(self):
        super().__init__()
        self.encodings: dict[str, set[str]] = {}

    def __call__(self, sample: zenoh.Sample) -> None:
        super().__call__(sample)
        stream = str(sample.key_expr).split("/", 2)[1]
        with self._lock:
            self.encodings.setdefault(stream, set()).add(str(sample.encoding))

class TwinClient:
    """One Python Zenoh peer connected to armtwin's listener."""

    def __init__(self, endpoint: str, subscribe: bool = True):
        """``subscribe``: collect every ``twin/**`` output. A client that only feeds and queries
        leaves it off, as a gateway does: armtwin's metrics wait on a subscriber's link, so a
        subscriber that falls behind slows the twins, and a gateway sharing its session has its
        puts held with them (docs/protocol/delivery.md)."""
        self.session = open_session(endpoint)
        self.collector = Collector()
        self.subscriber = self.session.declare_subscriber(f"{PREFIX}/**", self.collector) if subscribe else None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._closed = False

    def publisher(self, key: str) -> zenoh.Publisher:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(
                key,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
                allowed_destination=zenoh.Locality.REMOTE,  # our own twin/** does not count
            )
            self._publishers[key] = pub
        return pub

    def joints(self, robot: str) -> zenoh.Publisher:
        return self.publisher(f"{PREFIX}/joints/{robot}")

    def measured(self, robot: str) -> zenoh.Publisher:
        return self.publisher(f"{PREFIX}/measured/{robot}")

    def ready(self, robots, measured: bool = False, timeout: float = MATCH_TIMEOUT_S) -> None:
        """Declare the input publishers of ``robots``, wait until armtwin's subscribers match
        them and its state queryable matches, then do one ``get twin/state/**`` round trip so
        armtwin has processed our subscriber declaration (declarations and queries share the
        ordered link)."""
        pubs = [self.joints(r) for r in robots]
        if measured:
            pubs += [self.measured(r) for r in robots]
        if not wait_until(lambda: all(p.matching_status.matching for p in pubs), timeout):
            missing = [str(p.key_expr) for p in pubs if not p.matching_status.matching]
            raise AssertionError(f"armtwin's subscribers never matched {missing} within {timeout} s")
        querier = self.session.declare_querier(
            f"{PREFIX}/state/**", allowed_destination=zenoh.Locality.REMOTE, timeout=QUERY_TIMEOUT_S
        )
        try:
            if not wait_until(lambda: querier.matching_status.matching, timeout):
                raise AssertionError(f"armtwin's state queryable never matched within {timeout} s")
        finally:
            querier.undeclare()
        self.get(f"{PREFIX}/state/**")

    def put_json(self, pub: zenoh.Publisher, obj) -> None:
        pub.put(json.dumps(obj, allow_nan=False))

    def get(self, selector: str, payload: bytes | str | None = None, timeout: float = QUERY_TIMEOUT_S):
        """A bounded query; returns the list of replies once all queryables finished."""
        kwargs = {}
        if payload is not None:
            kwargs["payload"] = payload
        handler = self.session.get(
            selector,
            timeout=timeout,
            consolidation=zenoh.ConsolidationMode.NONE,
            allowed_destination=zenoh.Locality.REMOTE,
            **kwargs,
        )
        # The channel ends when every queryable sent its final reply or the timeout fires.
        return list(handler)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.session.close()
        except Exception:  # pragma: no cover - teardown must not mask the test's failure
            pass


def client_config(endpoint: str, tls: dict | None = None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([bounded_endpoint(endpoint)]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    for key, value in (tls or {}).items():
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    return conf


def open_client(endpoint: str, tls: dict | None = None) -> zenoh.Session:
    """A Zenoh client session of the router at ``endpoint``."""
    return zenoh.open(client_config(endpoint, tls))


def wait_queryable(session: zenoh.Session, key: str, timeout: float = 20.0) -> bool:
    """Whether a queryable (armtwin's, through the router) answers ``key`` within ``timeout``;
    then one query round trip, so that armtwin has also seen every subscriber ``session``
    declared before (declarations and queries keep their order on each link)."""
    querier = session.declare_querier(key, timeout=5.0)
    try:
        if not wait_until(lambda: querier.matching_status.matching, timeout):
            return False
    finally:
        querier.undeclare()
    list(session.get(key, timeout=10.0))
    return True


def paired_of(session: zenoh.Session, robot: str) -> int | None:
    """The robot's paired count from its state answer; ``None`` while it is not tracked (no reply),
    so that a wait polls on instead of failing on an empty answer."""
    answers = get_json(session, f"twin/state/{robot}")
    return answers[0][1]["metrics"]["paired"] if answers else None


def get_json(session: zenoh.Session, selector: str, timeout: float = 10.0) -> list[tuple[str, dict]]:
    replies = session.get(selector, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)
    out = []
    for reply in replies:
        if reply.ok is not None:
            out.append((str(reply.ok.key_expr), json.loads(reply.ok.payload.to_bytes())))
    return out


class Poses:
    """A dashboard's subscriber of one robot's poses (seq, arrival time)."""

    def __init__(self, session, robot: str):
        self.items: list[tuple[float, int]] = []
        self.sub = session.declare_subscriber(f"twin/pose/{robot}", self)

    def __call__(self, sample):
        self.items.append((time.monotonic(), json.loads(sample.payload.to_bytes())["seq"]))

    def seqs(self) -> list[int]:
        return [seq for _, seq in list(self.items)]


def wait_matched(publisher, timeout: float = 20.0) -> None:
    assert wait_until(lambda: publisher.matching_status.matching, timeout), (
        f"no subscriber of {publisher.key_expr} reached through the router"
    )


def description_publisher(session: zenoh.Session, robot: str, timeout: float = MATCH_TIMEOUT_S):
    """A publisher of ``robot``'s description (`twin/description/<robot>`, as a gateway puts it),
    once armtwin's subscriber matches: a put before that would reach no one."""
    publisher = session.declare_publisher(f"twin/description/{robot}")
    wait_matched(publisher, timeout)
    return publisher
