"""The firmware's host-link server: answers host commands and streams telemetry.

Entry points (used by ``firmware-sim run``)::

    from firmware_sim import link, transport
    port = transport.open_port(url)            # or transport.PtyPort()
    stats = link.serve(port, engine, key=None, stop_event=threading.Event())
    stats = link.serve_tcp(transport.TcpServer(host, port, key), engine, key=key,
                           stop_event=stop)    # several sessions at once

``serve`` blocks until ``stop_event`` is set or the port fails (a TCP peer closing);
``serve_tcp`` until ``stop_event`` is set, accepting up to ``MAX_SESSIONS`` connections.
Both return the link counters.  ``port`` is any pyserial-like object (``read(n)``,
``write(b)``, ``in_waiting``, ``timeout``); ``engine`` implements
``firmware_sim.engine.Engine``.  With a ``key`` every host frame except HELLO must carry a
valid HMAC tag and a fresh counter.

Sessions (docs/protocol.md, "Sessions"): one :class:`LinkServer` per connection, all of
one firmware sharing a :class:`Hub` (device-lifetime counters, the operator role, the
telemetry fan-out).  A HELLO asks for a role: ``operator`` (one at a time; a new operator
takes the role over, the previous one becomes a monitor and is told by a NOTICE) or
``monitor`` (read-only: telemetry, STATS, PARAM_GET, HEARTBEAT; other commands get NACK
FORBIDDEN).  On a keyed link a session gets its role, telemetry and answers only after
its first authentic frame: before that, nothing but HELLO/INFO.  TCP connections are
closed after ``pending_timeout_s`` without an authenticated HELLO, after ``idle_timeout_s``
without any frame, and after ``MAX_AUTH_FAILURES`` failed authentications (the peer's
address is then locked out for a growing time: its connections are still accepted, since
the operator may share the address, but each is closed at its first failed authentication,
which locks the address out again; a host with the key always gets in); authentication
failures are counted for the device's lifetime and logged with the peer's address, at most
one line per second.

Robustness rules (docs/protocol.md, "Reliability"): a frame with a bad CRC/COBS is
dropped and counted; a malformed, unknown or refused command gets a NACK and changes
nothing; a repeated command (same seq, type and payload) is answered from a cache and
not executed twice; an exception inside a handler is NACKed (INTERNAL) and counted,
never propagated; a snapshot that cannot be encoded is dropped and counted; anything else
that goes wrong in one session closes that session (reported through the engine), never
the link.  The link never blocks: writes are non-blocking; while more than
``TX_TELEMETRY_LIMIT`` bytes wait to be written to every session no snapshot is taken from
the engine (they wait in its bounded queue, which drops the oldest and counts them); other
frames are dropped (``tx_dropped``, and the host sees the sequence gap) only beyond
``TX_REPLY_LIMIT`` queued bytes (a host that sends but never reads).
"""
from __future__ import annotations

import os
import select
import sys
import threading
import time
import zlib
from collections import OrderedDict

import numpy as np
import serial

from springtrack import toml_bounds, wire
from springtrack.wire import MsgType, Nack, Notice, Role

from .engine import UpdateRejected
from .throttle import Throttle
from .validation import Validation

MAX_MODEL_BYTES = toml_bounds.MAX_TEXT_BYTES
REPLY_CACHE = 16
TX_TELEMETRY_LIMIT = 32 * 1024      # unwritten bytes above which no snapshot is taken
TX_REPLY_LIMIT = 1024 * 1024        # bytes queued before even replies are dropped (a host
                                    # that sends but never reads must not exhaust memory)
FIRMWARE_NAME = "firmware-sim"
MAX_SESSIONS = 8                    # TCP sessions with a role at once (operator + monitors);
                                    # twice as many connections may wait for their HELLO
PENDING_TIMEOUT_S = 5.0             # TCP: no authenticated HELLO within this: closed
IDLE_TIMEOUT_S = 30.0               # TCP: no frame from the host within this: closed
MAX_AUTH_FAILURES = 8               # failed authentications before a connection is closed
LOCKOUT_S = (1.0, 2.0, 5.0, 10.0, 30.0, 60.0)   # address lock-out after closing k times
LOCKOUT_FORGET_S = 600.0            # offences older than this are forgotten
POLL_S = 0.002                      # the link loop's wait for input
RX_MAX_GAP = 256                    # a host pipelines a few commands: a larger gap in its
                                    # sequence numbers is a jump (rx_seq_jumps), not a loss


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class Hub:
    """What every session of one firmware shares: the engine, the key, the operator role,
    the telemetry fan-out and the device-lifetime counters (``counts``; the counters of
    closed sessions are added to ``closed``)."""

    def __init__(self, engine, key: bytes | None = None, log=_stderr, on_shutdown=None,
                 energy_period_us: int = wire.ENERGY_PERIOD_US):
        wire.check_key(key)
        self.engine, self.key, self.log_line = engine, key, log
        self.on_shutdown = on_shutdown
        self.sessions: list[LinkServer] = []
        self.operator: LinkServer | None = None
        self.energy_period_us, self.next_energy_t = energy_period_us, None
        self.max_sessions = MAX_SESSIONS
        self.counts = dict(sessions_opened=0, sessions_closed=0, sessions_refused=0,
                           sessions_evicted=0, pending_timeouts=0, idle_timeouts=0, operator_takeovers=0,
                           auth_unsigned=0, auth_bad_tag=0, auth_replay=0, auth_disconnects=0,
                           auth_lockouts=0, telemetry_errors=0, session_faults=0,
                           uploads_validated=0, uploads_over_budget=0, uploads_busy=0)
        self.closed: dict = {}
        self.validation: Validation | None = None     # the upload being validated
        self.peers: dict[str, dict] = {}     # address -> offences, locked_until
        self.throttle = Throttle()           # at most one log line of a kind per second

    # ---- logging ------------------------------------------------------------------------
    def log(self, kind: str, text: str) -> None:
        """One line on the program's log, at most one of a ``kind`` per
        ``throttle.LOG_EVERY_S`` (the suppressed ones are counted in the next)."""
        line = self.throttle(kind, f"link: {text}")
        if line is not None:
            self.log_line(line)

    # ---- sessions ------------------------------------------------------------------------
    @property
    def receivers(self) -> list:
        return [s for s in self.sessions if s.receiving]

    def claim_operator(self, session) -> None:
        """``session`` is the operator now; the previous one becomes a monitor."""
        old = self.operator
        self.operator = session
        if old is not None and old is not session and old in self.sessions:
            self.counts["operator_takeovers"] += 1
            old.role = Role.MONITOR
            old.upload = None
            if not old.closing:
                old.notice(Notice.ROLE_CHANGED, f"the operator role was taken over by "
                                                f"{session.peer or 'another host'}: this "
                                                f"session is a monitor now (read-only)")
            self.log("takeover", f"operator role taken over by {session.peer or 'a host'} "
                                 f"from {old.peer or 'a host'}")

    def remove(self, session, reason: str = "") -> None:
        if session in self.sessions:
            self.sessions.remove(session)
            self.counts["sessions_closed"] += 1
            for k, v in session.stats().items():
                if isinstance(v, int):
                    self.closed[k] = self.closed.get(k, 0) + v
        if self.operator is session:
            self.operator = None
        session.closed_reason = session.closed_reason or reason

    def auth_failed(self, session, why: str) -> None:
        self.counts["auth_" + why] += 1
        session.counts["auth_" + why] += 1
        session.auth_failures += 1
        total = self.counts["auth_unsigned"] + self.counts["auth_bad_tag"] + self.counts["auth_replay"]
        self.log("auth", f"authentication failure ({why}) from {session.peer or 'the port'}: "
                         f"{session.auth_failures} on this connection, {total} since start")

    def locked_out(self, address: str) -> float:
        """Seconds the address is still locked out for (0: not locked)."""
        p = self.peers.get(address)
        return max(0.0, p["locked_until"] - time.monotonic()) if p else 0.0

    def punish(self, address: str) -> float:
        """The connection from ``address`` was closed for failed authentications: lock the
        address out for a time that grows with its recent offences; returns it."""
        now = time.monotonic()
        p = self.peers.setdefault(address, dict(offences=[], locked_until=0.0))
        p["offences"] = [t for t in p["offences"] if now - t < LOCKOUT_FORGET_S] + [now]
        s = LOCKOUT_S[min(len(p["offences"]) - 1, len(LOCKOUT_S) - 1)]
        p["locked_until"] = now + s
        if len(self.peers) > 1024:               # bounded: forget the oldest entries
            for a in sorted(self.peers, key=lambda a: self.peers[a]["locked_until"])[:512]:
                del self.peers[a]
        return s

    def validate(self, text: str) -> Validation:
        """Start validating an uploaded model text off the link's thread; one at a time per
        firmware (bounded memory): BUSY while another is still running."""
        if self.validation is not None and not self.validation.done.is_set():
            self.counts["uploads_busy"] += 1
            raise UpdateRejected(Nack.BUSY, "another model upload is being validated: retry "
                                            "in a second")
        self.validation = Validation(text)
        self.counts["uploads_validated"] += 1
        return self.validation

    # ---- the engine's outputs, fanned out ------------------------------------------------
    def pump(self) -> None:
        """Forward APPLIED reports, ERROR/NOTICE reports and snapshots to every session
        that receives (a role, authenticated); before there is one they wait in the
        engine's bounded queues (which drop the oldest and count them)."""
        receivers = self.receivers
        if not receivers:
            return
        applied = self.engine.poll_applied()
        for s in receivers:
            for gen, t_us in applied:
                s.send(MsgType.APPLIED, wire.encode_applied(gen, t_us))
        room = max((TX_TELEMETRY_LIMIT - len(s.txq)) // 256 for s in receivers)
        want = min(64, room)
        snaps = self.engine.poll_telemetry(want) if want > 0 else []   # else backpressure:
        for snap in snaps:                                             # they wait in the engine
            self._fan_out(receivers, MsgType.TELEMETRY, "telemetry_sent",
                          lambda: wire.encode_telemetry(
                              snap.t_us, snap.generation, snap.mean_energy, snap.records,
                              snap.trackers["state"], wire.quantise_velocities(snap.trackers)),
                          f"snapshot at t={snap.t_us} us")
            if snap.energies is not None:
                self._energies(snap, receivers)
        # ERRORs at once; a NOTICE (the stream ended) only after the snapshots before it
        drained = want > 0 and len(snaps) < want
        reports = self.engine.reports(min(s.report_cursor for s in receivers))
        for s in receivers:
            for rid, mtype, code, text in reports:
                if mtype == MsgType.NOTICE and not drained:
                    break
                if rid > s.report_cursor:
                    s.send(mtype, wire.encode_log(int(code), text))
                    s.report_cursor = rid

    def _energies(self, snap, receivers) -> None:
        """ENERGIES at most once per ``energy_period_us`` of event time, from the snapshots
        that carry ``energies = (kind index, per-connection array)``."""
        t = int(snap.t_us)
        if self.next_energy_t is not None and t < self.next_energy_t:
            return
        self.next_energy_t = t + self.energy_period_us
        kind, values = snap.energies
        self._fan_out(receivers, MsgType.ENERGIES, "energies_sent",
                      lambda: wire.encode_energies(t, kind, values), f"energies at t={t} us")

    def _fan_out(self, receivers, mtype, sent: str, encode, what: str) -> None:
        """Encode once, send to every receiver (droppable); a value that does not encode is
        dropped and counted (``telemetry_errors``), never the link's end."""
        try:
            payload = encode()
        except (wire.WireError, ValueError, OverflowError) as e:
            self.counts["telemetry_errors"] += 1
            self.log("telemetry", f"{what} dropped: {e}")
            return
        for s in receivers:
            if s.send(mtype, payload, droppable=True) is not None:
                s.counts[sent] += 1

    def discard_stale(self, session) -> None:
        """A session opens while nobody else receives: snapshots and APPLIED reports queued
        for nobody are discarded and counted, so that its stream starts now."""
        if any(s.receiving for s in self.sessions if s is not session):
            return
        stale = 0
        for _ in range(64):
            got = self.engine.poll_telemetry(256)
            if not got:
                break
            stale += len(got)
        self.engine.poll_applied()
        session.counts["telemetry_stale"] += stale

    def stats(self) -> dict:
        """Device-lifetime link counters: the hub's own, plus every session's counters
        summed (open and closed), plus ``sessions`` open now."""
        c = dict(self.closed)
        for s in self.sessions:
            for k, v in s.stats().items():
                if isinstance(v, int):
                    c[k] = c.get(k, 0) + v
        c.update(self.counts)
        c["sessions"] = len(self.sessions)
        c["operator"] = self.operator.peer if self.operator is not None else ""
        return c

    # ---- TCP: several connections ----------------------------------------------------------
    def serve_tcp(self, server, stop_event: threading.Event, heartbeat_s: float = 1.0,
                  pending_timeout_s: float = PENDING_TIMEOUT_S,
                  idle_timeout_s: float = IDLE_TIMEOUT_S, max_sessions: int = MAX_SESSIONS,
                  drain_s: float = 0.3) -> dict:
        """Accept and serve connections until ``stop_event`` is set."""
        try:
            self.max_sessions = max_sessions
            while not stop_event.is_set():
                self.tcp_step(server, heartbeat_s, pending_timeout_s, idle_timeout_s)
            self.shutting_down(drain_s)
        finally:
            for s in list(self.sessions):
                self.remove(s, "the firmware stopped")
                s.port.close()
        return self.stats()

    def tcp_step(self, server, heartbeat_s, pending_timeout_s, idle_timeout_s):
        fds = {s.fd: s for s in self.sessions if s.fd is not None}
        try:
            r, _, _ = select.select([server.sock, *fds], [], [], POLL_S)
        except (OSError, ValueError):            # a session's socket went bad meanwhile
            r = []
            for s in list(self.sessions):
                if not s.port.is_open:
                    self.remove(s, "socket closed")
        if server.sock in r:
            self.accept(server, heartbeat_s)
        for fd in r:
            s = fds.get(fd)
            if s is not None:
                self.guarded(s, s.read_and_handle, 0.0)
        self.pump()
        now = time.monotonic()
        for s in list(self.sessions):
            if s.dead:
                self.remove(s, s.dead)
                s.port.close()
                continue
            if s.closing:
                self.guarded(s, s._drain)
                if not s.txq or now > s.closing:
                    self.remove(s, s.closed_reason)
                    s.port.close()
                continue
            if not s.authenticated_role and now - s.opened > pending_timeout_s:
                self.counts["pending_timeouts"] += 1
                s.close_soon(f"no authenticated HELLO within {pending_timeout_s:g} s")
            elif now - s.last_rx > idle_timeout_s:
                self.counts["idle_timeouts"] += 1
                s.close_soon(f"idle for {idle_timeout_s:g} s (send a HEARTBEAT to stay)")
            elif s.auth_failures >= (1 if s.probation else MAX_AUTH_FAILURES):
                self.counts["auth_disconnects"] += 1
                ban = self.punish(s.address)
                self.log("auth", f"closing {s.peer}: {s.auth_failures} authentication "
                                 f"failures; {s.address} locked out for {ban:g} s")
                s.close_soon(f"{s.auth_failures} authentication failures")
            else:
                self.guarded(s, s.tick, now)

    def accept(self, server, heartbeat_s) -> None:
        port = server.accept(0)
        if port is None:
            return
        address = port.name.split()[-1].rsplit(":", 1)[0]
        # a locked-out address is not refused (the operator may share it: loopback, NAT),
        # its connections are on probation: closed at their first failed authentication
        wait = self.locked_out(address)
        if wait > 0:
            self.counts["auth_lockouts"] += 1
            self.log("lockout", f"connection from {address} on probation for {wait:.1f} s "
                                f"more after failed authentications: one failure closes it")
        if len(self.sessions) >= 2 * self.max_sessions:    # connections, not sessions:
            pending = [s for s in self.sessions if not s.authenticated_role]
            if not pending:                              # (cannot happen: at most
                self.counts["sessions_refused"] += 1     # max_sessions have a role)
                port.close()
                return
            old = min(pending, key=lambda s: s.opened)   # the oldest without a role goes
            self.counts["pending_timeouts"] += 1
            self.remove(old, "evicted: too many connections without a session")
            old.port.close()
        session = LinkServer(port, self.engine, hub=self, heartbeat_s=heartbeat_s)
        session.probation = wait > 0
        self.sessions.append(session)
        self.counts["sessions_opened"] += 1

    def admit(self, session) -> str:
        """``session`` is getting its role: "" if there is room (at most ``max_sessions``
        with a role; an operator always gets in, the session idle longest making room - the
        previous operator, which becomes a monitor, included), else why not."""
        others = [s for s in self.sessions
                  if s is not session and s.authenticated_role and not s.closing]
        if len(others) < self.max_sessions:
            return ""
        if session.role == Role.OPERATOR:     # (the operator it replaces is a monitor now)
            old = min(others, key=lambda s: s.last_rx)
            self.counts["sessions_evicted"] += 1
            old.close_soon(f"evicted: an operator needed a session (all {self.max_sessions} "
                           f"in use)")
            return ""
        self.counts["sessions_refused"] += 1
        self.log("refused", f"session of {session.peer or 'a host'} refused: all "
                            f"{self.max_sessions} sessions in use")
        return f"all {self.max_sessions} sessions are in use; try again later"

    def guarded(self, session, fn, *args) -> None:
        """Run a session's step; a peer gone closes it, anything else is a fault of this
        session (counted, reported, the session closed), never of the link."""
        try:
            fn(*args)
        except (OSError, serial.SerialException) as e:
            self.remove(session, str(e))
            session.port.close()
        except Exception as e:                   # noqa: BLE001 - one session, not the link
            self.counts["session_faults"] += 1
            self.engine.report_fault("host-link", e, "its session closed")
            self.remove(session, f"fault: {e}")
            session.port.close()

    def shutting_down(self, drain_s: float) -> None:
        """Tell every session the firmware is going, forward what is queued, flush."""
        end = time.monotonic() + drain_s
        for s in self.receivers:
            s.send(MsgType.NOTICE, wire.encode_notice(Notice.SHUTTING_DOWN,
                                                      "the firmware is shutting down"))
        for s in list(self.sessions):
            try:
                s.drain_telemetry(max(0.0, end - time.monotonic()))
            except (OSError, serial.SerialException):
                pass


class LinkServer:
    """One host session over one port (see the module docstring).  Without a ``hub`` it
    makes its own (a serial port or pty: one session, a new HELLO takes it over)."""

    def __init__(self, port, engine, key: bytes | None = None, heartbeat_s: float = 1.0,
                 energy_period_us: int = wire.ENERGY_PERIOD_US, hub: Hub | None = None,
                 on_shutdown=None, log=_stderr):
        if hub is None:
            hub = Hub(engine, key, log=log, on_shutdown=on_shutdown,
                      energy_period_us=energy_period_us)
            hub.counts["sessions_opened"] += 1
            hub.sessions.append(self)
        self.hub = hub
        self.port, self.engine = port, engine
        self.peer = port.name if isinstance(getattr(port, "name", None), str) else ""
        self.address = self.peer.split()[-1].rsplit(":", 1)[0] if self.peer else ""
        self.nonce = os.urandom(wire.NONCE_LEN)
        self.guard = wire.ReplayGuard(hub.key, self.nonce) if hub.key else None
        self.reader = wire.FrameReader()
        self.rx_seq = wire.SeqTracker(max_gap=RX_MAX_GAP)
        self.tx_seq = int.from_bytes(os.urandom(2), "little")
        self.txq = bytearray()
        self.replies: OrderedDict = OrderedDict()
        self.upload = None
        self.deferred = None                   # (MODEL_COMMIT frame, its cache key, Validation)
        self.role: Role | None = None          # asked for in HELLO (None: no HELLO yet)
        self.authenticated = self.guard is None
        self.auth_failures = 0
        self.probation = False                 # closed at its first failed authentication
        self.report_cursor = 0
        self.heartbeat_s = heartbeat_s
        self.t0 = time.monotonic()
        self.opened = self.last_rx = self.t0
        self.next_beat = self.t0 + heartbeat_s
        self.fd = _port_fd(port)
        self.closing = 0.0                     # close at this monotonic time (0: open)
        self.dead = ""                         # why writing to the port failed
        self._sent: list[bytes] = []
        self.closed_reason = ""
        self.counts = dict(rx_frames=0, rx_lost=0, rx_retries=0, auth_unsigned=0,
                           auth_bad_tag=0, auth_replay=0, version_refused=0, acks=0, nacks=0,
                           handler_errors=0, forbidden=0, tx_frames=0, tx_bytes=0,
                           tx_dropped=0, telemetry_sent=0, telemetry_stale=0,
                           tx_stale_bytes=0, energies_sent=0)

    # ---- roles ----------------------------------------------------------------------------
    @property
    def authenticated_role(self) -> bool:
        return self.role is not None and self.authenticated

    receiving = authenticated_role             # gets telemetry, reports, heartbeats

    @property
    def session(self) -> bool:
        """A host said HELLO (and, on a keyed link, authenticated)."""
        return self.authenticated_role

    @session.setter
    def session(self, value: bool) -> None:
        self.role = Role.OPERATOR if value else None
        if value:
            self.authenticated = True
            self.hub.claim_operator(self)

    @property
    def is_operator(self) -> bool:
        return self.hub.operator is self

    # ---- main loop (one port) -------------------------------------------------------------
    def serve(self, stop_event: threading.Event | None = None, drain_s: float = 2.0) -> dict:
        """Serve this port until ``stop_event`` is set or the peer goes (``drain_s``: time
        to forward what the engine still holds once stopped)."""
        stop_event = stop_event or threading.Event()
        try:
            self._send_raw(b"\x00")                 # end any garbage the host holds
            while not stop_event.is_set():
                self.step()
            self.hub.shutting_down(drain_s)
        except (OSError, serial.SerialException) as e:   # peer gone: end this session
            self.closed_reason = str(e)
        return self.stats()

    def drain_telemetry(self, timeout: float) -> None:
        """Forward the engine's queued snapshots and flush, within ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            before = self.counts["tx_frames"] + self.counts["tx_dropped"]
            self.hub.pump()
            self._drain()
            if self.counts["tx_frames"] + self.counts["tx_dropped"] == before and not self.txq:
                break
            if len(self.txq) > TX_TELEMETRY_LIMIT // 2 and self.fd is not None:
                select.select([], [self.fd], [], 0.01)
        self.flush(max(0.0, end - time.monotonic()))

    def step(self) -> None:
        """One iteration: read, handle, stream telemetry, heartbeat, write."""
        self.read_and_handle(POLL_S)
        self.hub.pump()
        self.tick(time.monotonic())
        if self.dead:
            raise serial.SerialException(self.dead)

    def read_and_handle(self, wait: float) -> None:
        # wait briefly for a byte, then take all that is there (in_waiting is not a byte
        # count on every pyserial port)
        wire.set_read_timeout(self.port, wait)
        data = self.port.read(1)
        if data:
            wire.set_read_timeout(self.port, 0)
            data += self.port.read(65536)
        if data:
            for frame in self.reader.feed(data):
                self.handle(frame)

    def tick(self, now: float) -> None:
        """Heartbeat, a validated upload's answer, and write."""
        if self.deferred is not None:
            self._answer_upload(now)
        if self.receiving and now >= self.next_beat:
            self.next_beat = now + self.heartbeat_s
            self.send(MsgType.HEARTBEAT, wire.encode_heartbeat(**self._beat()))
        self._drain()

    def close_soon(self, reason: str, linger_s: float = 0.5) -> None:
        """Tell the host why (a NOTICE), flush for up to ``linger_s``, then close."""
        self.closed_reason = reason
        self.notice(Notice.SESSION_CLOSING, f"closing this connection: {reason}")
        self.closing = time.monotonic() + linger_s
        self.hub.log("close", f"closing {self.peer or 'the session'}: {reason}")

    def notice(self, code: Notice, text: str) -> None:
        self.send(MsgType.NOTICE, wire.encode_notice(code, text))

    def stats(self) -> dict:
        c = dict(self.counts)
        c.update({f"rx_{k}": v for k, v in self.reader.counts.items() if k != "frames"})
        c["rx_seq_jumps"] = self.rx_seq.jumps
        return c

    # ---- sending ----------------------------------------------------------------
    def send(self, mtype: int, payload: bytes = b"", droppable: bool = False,
             version: int = wire.PROTOCOL_VERSION) -> bytes | None:
        if len(self.txq) > (TX_TELEMETRY_LIMIT if droppable else TX_REPLY_LIMIT):
            self.counts["tx_dropped"] += 1
            self.tx_seq = (self.tx_seq + 1) & 0xFFFF     # the host sees the gap
            return None
        # a leading delimiter too: a host attaching mid-stream skips to the first 0x00
        # (hunting) and still gets the next whole frame
        raw = b"\x00" + wire.encode_frame(mtype, self.tx_seq, payload, version=version)
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        self.counts["tx_frames"] += 1
        self._send_raw(raw)
        return raw

    def _send_raw(self, raw: bytes) -> None:
        self.txq += raw
        self.counts["tx_bytes"] += len(raw)
        self._drain()

    def _drain(self) -> None:
        """Write what the port accepts now without blocking (partial writes are fine)."""
        while self.txq:
            if self.fd is not None:
                _, w, _ = select.select([], [self.fd], [], 0)
                if not w:
                    return
            try:
                n = self.port.write(bytes(self.txq[:4096]))
            except (OSError, serial.SerialException) as e:    # the peer is gone: the hub
                self.dead = self.dead or f"write failed: {e}"  # closes this session
                self.txq.clear()
                return
            if not n:
                return
            del self.txq[:n]

    def flush(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        while self.txq and time.monotonic() < end:
            self._drain()
            if self.txq:
                time.sleep(0.001)

    def _beat(self) -> dict:
        c = self.counts
        rc = self.reader.counts
        return dict(uptime_us=int((time.monotonic() - self.t0) * 1e6),
                    rx_frames=c["rx_frames"],
                    rx_errors=rc["crc_errors"] + rc["cobs_errors"] + rc["malformed"] + rc["oversize"],
                    rx_lost=c["rx_lost"], tx_frames=c["tx_frames"], tx_dropped=c["tx_dropped"])

    # ---- receiving ----------------------------------------------------------------
    def handle(self, frame: wire.Frame) -> None:
        self.counts["rx_frames"] += 1
        self._sent = []                              # replies to this frame (for the cache)
        if self.closing:
            return
        if frame.version != wire.PROTOCOL_VERSION:
            self.counts["version_refused"] += 1
            self._nack(frame, Nack.VERSION_MISMATCH,
                       wire.version_reason(wire.PROTOCOL_VERSION, frame.version))
            return
        if self.guard is not None and frame.type != MsgType.HELLO:
            why = self.guard.check(frame)
            if why is not None:                      # dropped, counted, no answer (no oracle)
                self.hub.auth_failed(self, why)
                return
            if not self.authenticated:               # the first authentic frame
                self.authenticated = True
                refusal = self._open() if self.role is not None else ""
                if refusal:
                    self._nack(frame, Nack.FORBIDDEN, refusal)
                    return
        if self.guard is None and frame.flags & wire.FLAG_SIGNED:
            self._nack(frame, Nack.BAD_STATE, "signed frame on a link without a key: "
                                              "the tag cannot be checked, refused")
            return
        self.last_rx = time.monotonic()
        key = (frame.seq, frame.type, zlib.crc32(frame.payload))
        if key in self.replies:                      # a retry: answer again, do nothing
            self.counts["rx_retries"] += 1
            for raw in self.replies[key]:
                self._send_raw(raw)
            return
        if self.deferred is not None and key == self.deferred[1]:   # answered when validated
            self.counts["rx_retries"] += 1
            return
        if frame.type == MsgType.HELLO:              # a new session: expect anything next
            self.rx_seq.restart(frame.seq)
        else:
            self.counts["rx_lost"] += self.rx_seq.update(frame.seq)
        try:
            self._dispatch(frame)
        except UpdateRejected as e:
            self._nack(frame, e.code, str(e))
        except wire.WireError as e:
            self._nack(frame, Nack.MALFORMED, str(e))
        except Exception as e:                       # noqa: BLE001 - never crash the firmware
            self._internal(frame, e)
        if self.deferred is not None and self.deferred[0] is frame:
            self.deferred = (frame, key, self.deferred[2])          # answered later
            return
        self._cache(key)

    def _cache(self, key) -> None:
        self.replies[key] = self._sent
        while len(self.replies) > REPLY_CACHE:
            self.replies.popitem(last=False)

    def _answer_upload(self, now: float) -> None:
        """The answer to a MODEL_COMMIT once its validation has finished (or overrun its
        budget): the engine loads the validated model's canonical text (ACK with its
        generation), or a NACK says why not."""
        frame, key, job = self.deferred
        if not job.done.is_set() and not job.overdue(now):
            return
        self.deferred = None
        self._sent = []
        try:
            if job.overdue(now):
                self.hub.counts["uploads_over_budget"] += 1
            self._ack(frame, self.engine.load_model(job.result()))
        except UpdateRejected as e:
            self._nack(frame, e.code, str(e))
        except Exception as e:                       # noqa: BLE001 - never crash the firmware
            self._internal(frame, e)
        self._cache(key)

    def _internal(self, frame, e: Exception) -> None:
        """An exception inside a handler: NACK INTERNAL, counted, and logged (a defect)."""
        self.counts["handler_errors"] += 1
        what = f"{type(e).__name__}: {e}"
        name = MsgType(frame.type).name if frame.type in MsgType._value2member_map_ else frame.type
        self.hub.log("handler", f"{name} from {self.peer or 'the host'} raised {what[:300]}")
        self._nack(frame, Nack.INTERNAL, what)

    def _reply(self, mtype, payload=b"") -> None:
        raw = self.send(mtype, payload)
        if raw is not None:
            self._sent.append(raw)

    def _ack(self, frame, value: int = 0) -> None:
        self.counts["acks"] += 1
        self._reply(MsgType.ACK, wire.encode_ack(frame.seq, frame.type, value))

    def _nack(self, frame, code: Nack, reason: str) -> None:
        self.counts["nacks"] += 1
        raw = self.send(MsgType.NACK, wire.encode_nack(frame.seq, frame.type, code, reason))
        if raw is not None:
            self._sent.append(raw)

    def _dispatch(self, f: wire.Frame) -> None:
        handler = HANDLERS.get(f.type)
        if handler is None:
            self._nack(f, Nack.UNKNOWN_TYPE, f"message type 0x{f.type:02x} is not a host command")
            return
        if f.type not in wire.MONITOR_COMMANDS and not self.is_operator:
            self.counts["forbidden"] += 1
            who = ("no session: send HELLO first" if self.role is None else
                   f"this session is a monitor (read-only); the operator is "
                   f"{self.hub.operator.peer or 'another host'}" if self.hub.operator else
                   "this session is a monitor (read-only); HELLO as operator to take over")
            raise UpdateRejected(Nack.FORBIDDEN, f"{MsgType(f.type).name}: {who}")
        handler(self, f)

    # ---- command handlers ------------------------------------------------------------
    def on_hello(self, f) -> None:
        hello = wire.decode_hello(f.payload)
        if hello.version != wire.PROTOCOL_VERSION:
            self.counts["version_refused"] += 1
            self._nack(f, Nack.VERSION_MISMATCH,
                       wire.version_reason(wire.PROTOCOL_VERSION, hello.version))
            return
        self.role = hello.role
        refusal = self._open() if self.authenticated else ""
        if refusal:
            raise UpdateRejected(Nack.FORBIDDEN, refusal)
        info = dict(self.engine.info())
        info.setdefault("firmware", FIRMWARE_NAME)
        info.update(role=hello.role.name.lower(),
                    sessions=sum(1 for s in self.hub.sessions if s.authenticated_role))
        self._reply(MsgType.INFO, wire.encode_info(info, self.nonce, self.guard is not None))

    def _open(self) -> str:
        """This session gets its role (a HELLO, authenticated) and receives from now on;
        returns why not if all sessions are in use (the connection is then closed).
        Snapshots queued for nobody (produced before this session, or unread by a host that
        left) are discarded and counted, so that the host's stream starts now; unwritten
        frames of the previous session on this port are dropped likewise, except the
        remainder of a frame already partly written."""
        refusal = self.hub.admit(self)
        if refusal:
            self.role = None
            self.close_soon(refusal)
            return refusal
        if self.role == Role.OPERATOR:
            self.hub.claim_operator(self)
        elif self.hub.operator is self:
            self.hub.operator = None
        self.hub.discard_stale(self)
        self.report_cursor = max([r[0] for r in self.engine.reports(self.report_cursor)]
                                 + [self.report_cursor])
        # the frame being written is finished (up to its closing delimiter, the first 0x00
        # still queued), never cut: a cut frame would reach the new host as one CRC error
        keep = self.txq.find(0) + 1
        self.counts["tx_stale_bytes"] += len(self.txq) - keep
        del self.txq[keep:]
        return ""

    def on_model_begin(self, f) -> None:
        total, crc = wire.decode_model_begin(f.payload)
        if not 0 < total <= MAX_MODEL_BYTES:
            raise UpdateRejected(Nack.OUT_OF_RANGE, f"model of {total} bytes: must be 1..{MAX_MODEL_BYTES}")
        self.upload = dict(total=total, crc=crc, buf=bytearray(total), have=np.zeros(total, bool))
        self._ack(f)

    def on_model_chunk(self, f) -> None:
        offset, data = wire.decode_model_chunk(f.payload)
        up = self.upload
        if up is None:
            raise UpdateRejected(Nack.BAD_STATE, "MODEL_CHUNK without MODEL_BEGIN")
        if offset + len(data) > up["total"]:
            raise UpdateRejected(Nack.OUT_OF_RANGE,
                                 f"chunk {offset}+{len(data)} beyond the announced {up['total']} bytes")
        up["buf"][offset:offset + len(data)] = data
        up["have"][offset:offset + len(data)] = True
        self._ack(f)

    def on_model_commit(self, f) -> None:
        total, crc = wire.decode_model_begin(f.payload)
        up, self.upload = self.upload, None
        if up is None:
            raise UpdateRejected(Nack.BAD_STATE, "MODEL_COMMIT without MODEL_BEGIN")
        if (total, crc) != (up["total"], up["crc"]):
            raise UpdateRejected(Nack.INVALID_MODEL, "MODEL_COMMIT length/CRC differ from MODEL_BEGIN")
        missing = int((~up["have"]).sum())
        if missing:
            raise UpdateRejected(Nack.INVALID_MODEL, f"upload incomplete: {missing} of {total} bytes missing")
        if zlib.crc32(up["buf"]) != crc:
            raise UpdateRejected(Nack.INVALID_MODEL, "model text CRC-32 mismatch after upload")
        try:
            text = up["buf"].decode("utf-8")
        except UnicodeDecodeError as e:
            raise UpdateRejected(Nack.INVALID_MODEL, f"model text is not UTF-8: {e}") from None
        self.deferred = (f, None, self.hub.validate(text))     # answered by tick()

    def on_param_set(self, f) -> None:
        name, value = wire.decode_param_set(f.payload)
        self._ack(f, self.engine.set_param(name, value))

    def on_param_get(self, f) -> None:
        names = wire.decode_param_get(f.payload)
        params = self.engine.get_params()
        unknown = [n for n in names if n not in params]
        if unknown:
            raise UpdateRejected(Nack.UNKNOWN_NAME, f"unknown parameter(s) {', '.join(unknown)}; "
                                                 f"known: {', '.join(params)}")
        items = {n: params[n] for n in (names or params)}
        self._reply_parts(MsgType.PARAM_VALUE, f, items)

    def on_model_get(self, f) -> None:
        if f.payload:
            raise wire.WireError(f"MODEL_GET: a request has an empty payload, got {len(f.payload)} bytes")
        self._reply_parts(MsgType.MODEL_GET, f, wire.encode_model_text(self.engine.model_text()))

    def on_stats(self, f) -> None:
        if f.payload:
            raise wire.WireError(f"STATS: a request has an empty payload, got {len(f.payload)} bytes")
        items = {k: _scalar(v) for k, v in _flatten(self.engine.stats()).items()}
        items.update({f"link.{k}": _scalar(v) for k, v in self.hub.stats().items()})
        items.update({f"session.{k}": v for k, v in self.stats().items()},
                     **{"session.role": self.role.name.lower() if self.role is not None else "",
                        "session.operator": self.is_operator, "session.peer": self.peer})
        self._reply_parts(MsgType.STATS, f, items)

    def _reply_parts(self, mtype, f, items: dict) -> None:
        parts = wire.split_kv(items)
        for i, p in enumerate(parts):
            self._reply(mtype, wire.encode_reply_part(f.seq, i, len(parts), p))

    def on_simple(self, f) -> None:
        if f.payload:
            raise wire.WireError(f"{MsgType(f.type).name}: expects an empty payload, got {len(f.payload)} bytes")
        if f.type == MsgType.START:
            self.engine.start()
        elif f.type == MsgType.STOP:
            self.engine.stop()
        elif f.type == MsgType.RESET:
            self.upload = None
            self.engine.reset()
        elif f.type == MsgType.ACQUIRE:
            self._ack(f, self.engine.acquire())
            return
        self._ack(f)

    def on_shutdown(self, f) -> None:
        if f.payload:
            raise wire.WireError(f"SHUTDOWN: expects an empty payload, got {len(f.payload)} bytes")
        if self.hub.on_shutdown is None:
            raise UpdateRejected(Nack.BAD_STATE, "this link serves an engine without a program "
                                                 "to end (stop it where it was started)")
        self._ack(f)
        self.hub.log("shutdown", f"SHUTDOWN from {self.peer or 'the host'}")
        self.hub.on_shutdown()


HANDLERS = {
    MsgType.HELLO: LinkServer.on_hello,
    MsgType.MODEL_BEGIN: LinkServer.on_model_begin,
    MsgType.MODEL_CHUNK: LinkServer.on_model_chunk,
    MsgType.MODEL_COMMIT: LinkServer.on_model_commit,
    MsgType.PARAM_SET: LinkServer.on_param_set,
    MsgType.PARAM_GET: LinkServer.on_param_get,
    MsgType.STATS: LinkServer.on_stats,
    MsgType.MODEL_GET: LinkServer.on_model_get,
    MsgType.START: LinkServer.on_simple,
    MsgType.STOP: LinkServer.on_simple,
    MsgType.RESET: LinkServer.on_simple,
    MsgType.SHUTDOWN: LinkServer.on_shutdown,
    MsgType.ACQUIRE: LinkServer.on_simple,
    MsgType.HEARTBEAT: LinkServer.on_simple,
}


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _scalar(v):
    if isinstance(v, np.generic):
        v = v.item()
    return v if isinstance(v, (bool, int, float, str)) else str(v)


def _port_fd(port):
    """The file descriptor to poll for writability, if the port has one."""
    try:
        return port.fileno()
    except Exception:                                # noqa: BLE001 - no fd on this port type
        sock = getattr(port, "_socket", None)
        return sock.fileno() if sock is not None else None


def _switch(switch_interval: float | None) -> None:
    """The link thread needs the GIL for every read, reply and telemetry frame; with
    Python's default 5 ms switch interval a busy simulation thread delays each of those
    steps by up to 5 ms, so the process's interval is lowered (None: left alone)."""
    if switch_interval is not None:
        sys.setswitchinterval(min(sys.getswitchinterval(), switch_interval))


def serve(port, engine, key: bytes | None = None, stop_event: threading.Event | None = None,
          switch_interval: float | None = 0.0005, **kw) -> dict:
    """Serve one host link (a serial port or pty) until ``stop_event`` is set; returns the
    link counters.  ``kw``: :class:`LinkServer` options (``on_shutdown``, ``log``, ...)."""
    _switch(switch_interval)
    drain_s = kw.pop("drain_s", 2.0)
    server = LinkServer(port, engine, key=key, **kw)
    server.serve(stop_event, drain_s=drain_s)
    return server.hub.stats()


def serve_tcp(server, engine, key: bytes | None = None,
              stop_event: threading.Event | None = None,
              switch_interval: float | None = 0.0005, on_shutdown=None, log=_stderr,
              hub: Hub | None = None, **kw) -> dict:
    """Serve every connection of ``server`` (a ``transport.TcpServer``) until
    ``stop_event`` is set; ``kw``: :meth:`Hub.serve_tcp` limits."""
    _switch(switch_interval)
    hub = hub or Hub(engine, key, log=log, on_shutdown=on_shutdown)
    return hub.serve_tcp(server, stop_event or threading.Event(), **kw)
