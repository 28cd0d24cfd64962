"""The paho-mqtt adapter: the one module that imports paho, driven by the asyncio loop.

How paho meets asyncio here:

* **Socket hooks.** paho's `on_socket_open` / `on_socket_register_write` hooks
  put its socket into the loop (`add_reader` → `loop_read`, `add_writer` →
  `loop_write`), as in paho's own asyncio example, and a `call_later` timer
  runs `loop_misc` (keepalive) once a second. Every paho callback (CONNACK,
  PUBACK, incoming `/set` messages, connection loss) therefore runs on the
  loop's thread, and `publish()` only queues bytes: nothing awaits per message.
* **Connecting off the loop.** paho opens its socket (DNS, TCP, TLS handshake)
  with blocking calls. That part, `Client.reconnect()`, runs in a short-lived
  daemon thread while nothing else touches the client; the hooks it fires
  there are replayed on the loop afterwards. A broker that does not answer
  therefore never stalls the OPC UA server, and shutdown never waits for it.
* **Errors.** paho's return codes, reason codes and socket/TLS exceptions
  become BrokerError / BrokerRefused with a sentence a person can act on.
* **Batches of QoS 0.** `publish_packets()` queues QoS 0 PUBLISH packets that the
  sink encoded itself (gateway/codecs/mqtt_publish.py) as one write: none of
  paho's per-message objects, one socket write per batch instead of one per
  message. `on_drained` says when paho has handed everything to the socket, so
  that the sink gives it the next batch only then (the newest values, not a queue).
* **QoS 1 on the same path** (issue 28). `packet_id()` hands out packet
  identifiers from paho's own counter, skipping any still in use by either of
  us, so that the two never share one; the sink encodes QoS 1 PUBLISH packets
  with them and writes them with `write_packets`, like QoS 0. paho does not know
  these messages: their PUBACKs are taken out of the receive buffer before paho
  reads it (`read_puback`) and handed to `on_acked` in bulk, one call for all
  that one read brought.
* **One read per wake-up.** paho reads a packet with three `recv` calls (its
  type, its length, its body). `_LimitedClient` reads what the socket holds
  (up to 256 KiB) in one, and serves paho's reads from that buffer.
* **PUBACKs without objects.** For each PUBACK paho builds a ReasonCode (which
  copies its table of reason names) and a Properties; a PUBACK of two bytes
  (success, no properties: nearly all of them) gets one shared pair instead
  (`_shared_success_acks`), the same values. At start-up, 10,000 QoS 1 values
  took about 0.15 s of CPU in that alone.
* **No hidden queues.** paho's automatic re-sending after a reconnect is not
  used: `take_back()` empties paho's unacknowledged messages when the
  connection drops, and the sink re-sends them from its own backlog, so that
  there is one place that knows what the broker has not confirmed.
* **No packet larger than `max_packet_size`.** paho reads a whole packet into
  memory before anything can look at it (with one `recv` of its full length),
  so a 120 MB PUBLISH to a `/set` topic cost 120 MB and more before the payload
  check refused it (two raised the gateway from 97 to 468 MB). With MQTT 5 the
  CONNECT says the limit (Maximum Packet Size) and the broker drops a larger
  message for us; with either version `_LimitedClient` ends the connection as
  soon as a packet's fixed header announces more (MQTT 3.1.1 has no way to
  tell the broker: its own limit must be set), and says so.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import socket
import ssl
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import paho.mqtt.client as paho
from paho.mqtt import _packet
from paho.mqtt.enums import CallbackAPIVersion, MessageType, MQTTErrorCode, MQTTProtocolVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from gateway.codecs.mqtt_publish import FAILURE, read_puback
from gateway.errors import BrokerError, BrokerRefused, SinkError
from gateway.shards.identity import shard_index
from gateway.sinks.mqtt_link.broker import MqttTls

# paho's Properties() has no annotations, which mypy --strict will not call; this is its signature.
_properties = cast(Callable[[int], Properties], Properties)

log = logging.getLogger("gateway.sinks.mqtt.client")  # the name log filters knew before the link moved here

PUBLISH = MessageType.PUBLISH
MISC_INTERVAL = 1.0  # s between paho.loop_misc calls (keepalive pings, dead-connection detection)
READ_SIZE = 262_144  # bytes taken from the socket in one recv at most


def _shared_success_acks() -> None:
    """Decode two-byte PUBACKs (message id only: success, no properties) to one shared ReasonCode and
    Properties, as paho would build them anew for each (once per process; the rest go to paho)."""
    decode = _packet.decode_puback
    if getattr(decode, "_shared_success", False):
        return
    reason = ReasonCode(PacketTypes.PUBACK)
    properties = _properties(PacketTypes.PUBACK)

    def decode_puback(header: int, packet: bytes | bytearray, protocol: MQTTProtocolVersion) -> Any:
        if len(packet) == 2:
            return _packet.PubackPacket(
                mid=(packet[0] << 8) | packet[1], reason=reason, properties=properties
            )
        return decode(header, packet, protocol)

    decode_puback._shared_success = True  # type: ignore[attr-defined]
    _packet.decode_puback = decode_puback


class _LimitedClient(paho.Client):
    """paho's client reading from a buffer that `fill()` loads with one `recv`, and refusing an incoming
    packet larger than `max_packet_size` once its fixed header says so, before any of its body is read
    (paho would read it whole: one `recv` of its full length)."""

    max_packet_size: int | None = None
    oversized: int | None = None  # the size of the packet that ended the connection, until it is reported

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.received = bytearray()  # read from the socket, not yet taken (by paho or by `read_puback`)
        self.taken = 0  # how much of `received` is taken
        self.ended: OSError | None = None  # how the socket ended (EOF: ConnectionResetError), once it did

    def fill(self) -> int:
        """Read what the socket holds (TLS: with what it has decrypted); the number of bytes read."""
        if self.taken:
            del self.received[: self.taken]
            self.taken = 0
        got = 0
        while self.ended is None:
            try:
                data = super()._sock_recv(READ_SIZE)
            except BlockingIOError:
                break
            except OSError as exc:
                self.ended = exc
                break
            if not data:
                self.ended = ConnectionResetError(errno.ECONNRESET, "the broker closed the connection")
                break
            self.received += data
            got += len(data)
            # One read a wake-up (a huge packet is refused by its header, not read whole), and what TLS
            # has decrypted already, which the selector cannot see.
            if getattr(self._sock, "pending", _zero)() == 0:
                break
        if got:
            self._last_bytes_received = paho.time_func()
        return got

    @property
    def buffered(self) -> int:
        return len(self.received) - self.taken

    @property
    def at_packet_start(self) -> bool:
        """paho is between packets (has read no part of the next one)."""
        return self._in_packet["command"] == 0

    def forget_received(self) -> None:
        self.received.clear()
        self.taken = 0
        self.ended = None

    def _sock_recv(self, bufsize: int) -> bytes:
        packet = self._in_packet
        limit = self.max_packet_size
        if limit is not None and packet["have_remaining"]:
            size = 1 + len(packet["remaining_count"]) + packet["remaining_length"]  # fixed header + the rest
            if size > limit:
                self.oversized = size
                raise OSError(errno.EMSGSIZE, f"a packet of {size} bytes, more than max_packet_size {limit}")
        start = self.taken
        if start >= len(self.received):
            if self.ended is None:
                raise BlockingIOError(errno.EAGAIN, "nothing buffered")
            if isinstance(self.ended, ConnectionResetError) and self.ended.errno == errno.ECONNRESET:
                return b""  # paho's way of seeing the end of the stream
            raise self.ended
        end = min(start + bufsize, len(self.received))
        self.taken = end
        return bytes(self.received[start:end])


@dataclass(frozen=True, slots=True)
class Will:
    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = True


@dataclass(frozen=True)
class BrokerSettings:
    host: str
    port: int
    client_id: str
    username: str | None = None
    password: str | None = None
    protocol: str = "3.1.1"  # or "5"
    keepalive: int = 30
    connect_timeout: float = 5.0
    tls: ssl.SSLContext | None = None
    tls_verify: bool = True
    will: Will | None = None
    no_delay: bool = (
        False  # TCP_NODELAY: small packets (a fence after a publish) go out at once, not after an ACK
    )
    max_packet_size: int | None = None  # bytes taken from the broker at most (MQTT 5: told in the CONNECT)

    @property
    def address(self) -> str:
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}"


@dataclass(frozen=True, slots=True)
class Incoming:
    """A message the broker delivered to us (a write request)."""

    topic: str
    payload: bytes
    qos: int
    retain: bool = False  # set only for messages the broker kept (sent because we subscribed)
    response_topic: str | None = None
    correlation_data: bytes | None = None


@dataclass(frozen=True, slots=True)
class Connected:
    session_present: bool
    receive_maximum: int | None  # MQTT v5: how many unacknowledged QoS 1/2 messages the broker accepts


def tls_context(tls: MqttTls, base_dir: Path) -> ssl.SSLContext:
    """An SSLContext for the broker, verifying its certificate and host name unless told not to."""
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH)
    try:
        if tls.ca:
            ctx.load_verify_locations(cafile=str(base_dir / tls.ca))
        if tls.cert:
            password = tls.key_password.get_secret_value() if tls.key_password else None
            ctx.load_cert_chain(
                str(base_dir / tls.cert), str(base_dir / tls.key) if tls.key else None, password
            )
    except (OSError, ssl.SSLError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or getattr(exc, "reason", None) or str(exc)
        files = ", ".join(str(base_dir / f) for f in (tls.ca, tls.cert, tls.key) if f)
        raise SinkError(f"mqtt.tls: cannot load {files}: {reason}") from None
    if not tls.verify:
        ctx.check_hostname = False
        ctx.verify_mode = ssl.CERT_NONE
    return ctx


def default_client_id() -> str:
    """`cnc-gateway-<host>`, and `-shard-K` for shard K of a fleet: the shards of one host must not take
    each other's connection, and a restarted shard resumes its own persistent session."""
    host = "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in socket.gethostname())
    shard = shard_index()
    return (f"cnc-gateway-{host}" + (f"-shard-{shard}" if shard is not None else ""))[-64:]


class MqttClient:
    """One broker connection at a time, on the running loop; `connect()` again after a loss."""

    def __init__(
        self,
        settings: BrokerSettings,
        *,
        on_message: Callable[[Incoming], None],
        on_published: Callable[[int], None],
        on_lost: Callable[[str], None],
        on_unsubscribed: Callable[[int], None] | None = None,
        on_drained: Callable[[], None] | None = None,
        on_acked: Callable[[list[tuple[int, int]]], None] | None = None,
    ) -> None:
        self.settings = settings
        self.on_drained = on_drained
        self.on_acked = on_acked  # PUBACKs of `packet_id()` messages: (packet id, reason code), in bulk
        self._ours: set[int] = set()  # packet ids handed out by `packet_id()` and not acknowledged yet
        self.on_message = on_message
        self.on_published = on_published
        self.on_lost = on_lost
        self.on_unsubscribed = on_unsubscribed
        self.v5 = settings.protocol == "5"
        protocol = MQTTProtocolVersion.MQTTv5 if self.v5 else MQTTProtocolVersion.MQTTv311
        kwargs: dict[str, Any] = {} if self.v5 else {"clean_session": True}
        client = _LimitedClient(
            CallbackAPIVersion.VERSION2,
            client_id=settings.client_id,
            protocol=protocol,
            reconnect_on_failure=False,  # also stops paho reconnecting (blocking) on its own
            **kwargs,
        )
        client.max_packet_size = settings.max_packet_size
        self.oversized_packets = 0  # packets over max_packet_size that ended a connection
        _shared_success_acks()
        client.suppress_exceptions = True
        client.max_inflight_messages_set(0)  # the sink keeps its own window
        client.max_queued_messages_set(0)
        client.connect_timeout = settings.connect_timeout
        if settings.username is not None:
            client.username_pw_set(settings.username, settings.password)
        if settings.tls is not None:
            client.tls_set_context(settings.tls)
            if not settings.tls_verify:
                client.tls_insecure_set(True)
        if settings.will is not None:
            w = settings.will
            client.will_set(w.topic, w.payload, w.qos, w.retain)
        client.on_socket_open = self._hook_open
        client.on_socket_close = self._hook_close
        client.on_socket_register_write = self._hook_want_write
        client.on_socket_unregister_write = self._hook_done_write
        client.on_connect = self._paho_connect
        client.on_disconnect = self._paho_disconnect
        client.on_publish = self._paho_publish
        client.on_message = self._paho_message
        client.on_subscribe = self._paho_subscribe
        client.on_unsubscribe = self._paho_unsubscribe
        self._client: _LimitedClient = client
        self._configured = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._sock: Any = None
        self._deferred_open: Any = None
        self._connack: asyncio.Future[Connected] | None = None
        self._misc: asyncio.TimerHandle | None = None
        self._connected = False
        self._closed = False
        self._suback_failures: Callable[[list[str]], None] | None = None
        self._pending_subs: dict[int, list[str]] = {}

    # --- state -------------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def queued_bytes_pending(self) -> int:
        """Packets paho holds that the socket has not taken yet (a slow or stuck broker)."""
        return len(self._client._out_packet)

    @property
    def queued_packets(self) -> int:
        """Writes paho holds that the socket has not taken yet (a batch of `publish_packets` is one)."""
        return len(self._client._out_packet)

    # --- connecting --------------------------------------------------------------------------

    async def connect(self) -> Connected:
        """Open a connection and wait for the broker's CONNACK. Raises BrokerError / BrokerRefused."""
        if self._closed:
            raise BrokerError("the MQTT client is closed")
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._loop_thread = threading.get_ident()
        self._drop_socket()
        client, s = self._client, self.settings
        if not self._configured:
            kwargs: dict[str, Any] = {}
            if self.v5:
                kwargs["clean_start"] = True
                if s.max_packet_size is not None:
                    props = _properties(PacketTypes.CONNECT)
                    props.MaximumPacketSize = s.max_packet_size
                    kwargs["properties"] = props
            client.connect_async(s.host, s.port, s.keepalive, **kwargs)
            self._configured = True
        opened: asyncio.Future[BaseException | None] = loop.create_future()
        abandoned = threading.Event()

        def work() -> None:
            error: BaseException | None = None
            try:
                client.reconnect()
            except BaseException as exc:  # noqa: BLE001 - every failure is reported to the loop below
                error = exc
            if abandoned.is_set():
                _close_quietly(self._deferred_open)
                return
            try:
                loop.call_soon_threadsafe(_resolve, opened, error)
            except RuntimeError:  # the loop is gone: we are shutting down
                _close_quietly(self._deferred_open)

        threading.Thread(target=work, name=f"mqtt-connect-{s.host}:{s.port}", daemon=True).start()
        try:
            error = await opened
        except asyncio.CancelledError:
            abandoned.set()
            raise
        if error is not None:
            self._deferred_open = None
            raise _translate(error, s)
        sock, self._deferred_open = self._deferred_open, None
        if sock is None:  # pragma: no cover - paho always opens a socket when reconnect() returns
            raise BrokerError(f"cannot connect to {s.address}: no socket")
        self._attach(sock)
        self._connack = loop.create_future()
        try:
            async with asyncio.timeout(s.connect_timeout):
                result = await self._connack
        except TimeoutError:
            self._drop_socket()
            raise BrokerError(
                f"{s.address} did not answer the MQTT CONNECT within {s.connect_timeout:g} s"
            ) from None
        except BaseException:
            self._drop_socket()
            raise
        finally:
            self._connack = None
        self._connected = True
        self._misc = loop.call_later(MISC_INTERVAL, self._run_misc)
        return result

    def _attach(self, sock: Any) -> None:
        loop = self._loop
        assert loop is not None
        self._sock = sock
        if self.settings.no_delay:
            with contextlib.suppress(OSError, AttributeError):  # not a TCP socket: nothing to turn off
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        loop.add_reader(sock, self._readable)
        if self._client.want_write():
            loop.add_writer(sock, self._writable)

    def _drop_socket(self) -> None:
        """Close the socket without a DISCONNECT (paho calls our close hook)."""
        self._connected = False
        if self._misc is not None:
            self._misc.cancel()
            self._misc = None
        if self._sock is not None:
            self._client._sock_close()
        self._client.forget_received()

    # --- paho's socket hooks -----------------------------------------------------------------

    def _on_loop(self) -> bool:
        return threading.get_ident() == self._loop_thread

    def _hook_open(self, client: paho.Client, userdata: Any, sock: Any) -> None:
        if self._on_loop() and self._sock is None and self._connack is not None:
            self._attach(sock)
        else:  # inside reconnect() on the connecting thread: attached when it returns
            self._deferred_open = sock

    def _hook_close(self, client: paho.Client, userdata: Any, sock: Any) -> None:
        if sock is not self._sock or self._loop is None:
            return
        self._sock = None
        if self._on_loop():
            self._loop.remove_reader(sock)
            self._loop.remove_writer(sock)

    def _hook_want_write(self, client: paho.Client, userdata: Any, sock: Any) -> None:
        if sock is self._sock and self._loop is not None and self._on_loop():
            self._loop.add_writer(sock, self._writable)

    def _hook_done_write(self, client: paho.Client, userdata: Any, sock: Any) -> None:
        if sock is self._sock and self._loop is not None and self._on_loop():
            self._loop.remove_writer(sock)

    def _readable(self) -> None:
        """Read what arrived: our PUBACKs straight from the buffer, in bulk; every other packet through
        paho, one at a time, from the same buffer."""
        client = self._client
        client.fill()
        sock = self._sock
        ours = self._ours
        acks: list[tuple[int, int]] = []
        try:
            while sock is not None and sock is self._sock:
                if ours and client.at_packet_start:
                    received, pos = client.received, client.taken
                    while True:
                        try:
                            ack = read_puback(received, pos)
                        except ValueError:
                            ack = None  # malformed: paho reads it, and ends the connection
                        if ack is None or ack[0] not in ours:
                            break
                        ours.discard(ack[0])
                        acks.append((ack[0], ack[1]))
                        pos = ack[2]
                    client.taken = pos
                if client.buffered == 0 and client.ended is None:
                    break
                if client.loop_read() != MQTTErrorCode.MQTT_ERR_SUCCESS:
                    break
        finally:
            if acks:
                self._acked(acks)

    def _acked(self, acks: list[tuple[int, int]]) -> None:
        refused = [(mid, reason) for mid, reason in acks if reason >= FAILURE]
        for _mid, reason in refused[:1]:
            log.warning(
                "the broker did not accept %d message(s) (%s)",
                len(refused),
                _reason_text(ReasonCode(PacketTypes.PUBACK, identifier=reason)),
            )
        if self.on_acked is not None:
            self.on_acked(acks)

    def _writable(self) -> None:
        client = self._client
        client.loop_write()
        if not client._out_packet and self.on_drained is not None:
            self.on_drained()

    def _run_misc(self) -> None:
        self._misc = None
        if self._sock is None:
            return
        self._client.loop_misc()
        if self._sock is not None and self._loop is not None:
            self._misc = self._loop.call_later(MISC_INTERVAL, self._run_misc)

    # --- paho's callbacks (all on the loop's thread) -----------------------------------------

    def _paho_connect(
        self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any
    ) -> None:
        fut = self._connack
        if fut is None or fut.done():
            return
        if reason.is_failure:
            fut.set_exception(
                BrokerRefused(f"{self.settings.address} refused the connection: {_reason_text(reason)}")
            )
            return
        receive_max = getattr(properties, "ReceiveMaximum", None) if self.v5 else None
        fut.set_result(Connected(bool(getattr(flags, "session_present", False)), receive_max))

    def _paho_disconnect(
        self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any
    ) -> None:
        was = self._connected
        self._connected = False
        self._ours.clear()  # the caller sends its unacknowledged messages again, with new packet ids
        if self._misc is not None:
            self._misc.cancel()
            self._misc = None
        text = _reason_text(reason)
        size, self._client.oversized = self._client.oversized, None
        if size is not None:
            self.oversized_packets += 1
            limit = self.settings.max_packet_size
            text = f"the broker sent a packet of {size} bytes, more than max_packet_size {limit}"
            log.warning(
                "MQTT %s: %s: dropped unread with the connection%s",
                self.settings.address,
                text,
                ""
                if self.v5
                else " (MQTT 3.1.1 cannot tell the broker the limit: set the broker's own, "
                "mosquitto's message_size_limit, or use protocol 5)",
            )
        fut = self._connack
        if fut is not None and not fut.done():
            fut.set_exception(
                BrokerError(f"{self.settings.address} closed the connection during CONNECT: {text}")
            )
        if was and not self._closed and self._loop is not None:
            # Outside paho's stack: the sink takes messages back and may publish again.
            self._loop.call_soon(self.on_lost, text)

    def _paho_publish(
        self, client: paho.Client, userdata: Any, mid: int, reason: Any, properties: Any
    ) -> None:
        if reason.is_failure:
            log.warning("the broker did not accept a message (%s)", _reason_text(reason))
        self.on_published(mid)

    def _paho_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        try:
            topic = msg.topic
        except UnicodeDecodeError:
            log.debug("ignored a message whose topic is not UTF-8")
            return
        response_topic = correlation = None
        props = msg.properties
        if props is not None:
            response_topic = getattr(props, "ResponseTopic", None)
            correlation = getattr(props, "CorrelationData", None)
        try:
            self.on_message(
                Incoming(topic, bytes(msg.payload), msg.qos, bool(msg.retain), response_topic, correlation)
            )
        except Exception:  # a bug in a handler must not take the connection down with it
            log.exception("handling an MQTT message on %s failed", topic[:200])

    def _paho_subscribe(
        self, client: paho.Client, userdata: Any, mid: int, reasons: list[Any], properties: Any
    ) -> None:
        filters = self._pending_subs.pop(mid, [])
        refused = [f for f, r in zip(filters, reasons, strict=False) if r.is_failure]
        if refused:
            log.error(
                "the broker refused the subscription to %s: writes over MQTT will not arrive (check its ACL)",
                ", ".join(refused),
            )

    def _paho_unsubscribe(
        self, client: paho.Client, userdata: Any, mid: int, reasons: list[Any], properties: Any
    ) -> None:
        if self.on_unsubscribed is not None:
            self.on_unsubscribed(mid)

    # --- operations --------------------------------------------------------------------------

    def publish(
        self, topic: str, payload: bytes, qos: int, retain: bool, *, correlation_data: bytes | None = None
    ) -> int:
        """Queue one message on the socket; returns its message id (for `on_published`)."""
        props = None
        if correlation_data is not None and self.v5:
            props = _properties(PacketTypes.PUBLISH)
            props.CorrelationData = correlation_data
        try:
            info = self._client.publish(topic, payload, qos, retain, props)
        except ValueError as exc:
            raise BrokerError(f"cannot publish to {topic[:200]!r}: {exc}") from None
        if info.rc not in (MQTTErrorCode.MQTT_ERR_SUCCESS, MQTTErrorCode.MQTT_ERR_NO_CONN):
            raise BrokerError(f"cannot publish to {topic[:200]!r}: {paho.error_string(info.rc)}")
        return info.mid

    def publish_packets(self, packets: bytes) -> None:
        """Write QoS 0 PUBLISH packets, encoded by the caller, as one write (nothing to acknowledge).

        Uses paho's packet queue, so that they keep their place among paho's own packets (a PUBLISH
        at QoS 1 before them is written before them); paho calls `on_published` once, for the batch.
        """
        client = self._client
        if not self._connected or self._sock is None:
            raise BrokerError("not connected to the broker")
        mid = client._mid_generate()
        client._packet_queue(PUBLISH, packets, mid, 0, paho.MQTTMessageInfo(mid))
        self._writable()  # now, not at the loop's next turn: what the socket does not take waits for it

    def packet_id(self) -> int:
        """A packet identifier for a QoS 1 PUBLISH the caller encodes, unique among those in flight (ours
        and paho's: SUBSCRIBE, UNSUBSCRIBE, its own publications); its PUBACK goes to `on_acked`."""
        client, ours = self._client, self._ours
        in_use = client._out_messages
        for _ in range(65_536):
            mid = client._mid_generate()
            if mid not in ours and mid not in in_use and mid not in self._pending_subs:
                ours.add(mid)
                return mid
        raise BrokerError("every MQTT packet identifier is in use")  # pragma: no cover - window ≤ 65,000

    def write_packets(self, packets: bytes) -> None:
        """Write PUBLISH packets at QoS 1 (with ids from `packet_id()`), encoded by the caller, as one write.

        Queued behind what paho already holds, like `publish_packets`; paho is told nothing about them
        (its `on_published` is not called: the PUBACKs go to `on_acked`).
        """
        client = self._client
        if not self._connected or self._sock is None:
            raise BrokerError("not connected to the broker")
        client._packet_queue(PUBLISH, packets, 0, 1, None)
        self._writable()

    @property
    def unacknowledged(self) -> int:
        """Packet ids from `packet_id()` whose PUBACK has not come."""
        return len(self._ours)

    def publish_reply(self, topic: str, payload: bytes, correlation_data: bytes | None = None) -> None:
        """An answer to a request: QoS 1, not retained, with the request's correlation data (MQTT v5)."""
        self.publish(topic, payload, 1, False, correlation_data=correlation_data)

    def subscribe(self, filters: list[str], qos: int = 1) -> None:
        if not filters:
            return
        rc, mid = self._client.subscribe([(f, qos) for f in filters])
        if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or mid is None:
            raise BrokerError(f"cannot subscribe: {paho.error_string(rc)}")
        self._pending_subs[mid] = filters

    def unsubscribe(self, filters: list[str]) -> int:
        """Queue an UNSUBSCRIBE; returns its message id, which `on_unsubscribed` gets with the UNSUBACK.

        A broker answers the packets of one connection in order, so the UNSUBACK also says that it has
        taken every message published before it: the one acknowledgement QoS 0 messages can have.
        """
        rc, mid = self._client.unsubscribe(filters)
        if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or mid is None:
            raise BrokerError(f"cannot unsubscribe: {paho.error_string(rc)}")
        return mid

    def take_back(self) -> int:
        """Forget every message paho still holds unacknowledged (the caller re-sends its own copies)."""
        return len(self._client.drop_out_messages())

    async def disconnect(self, timeout: float = 1.0) -> None:
        """Say goodbye (the broker then does not publish the will) and close."""
        self._closed = True
        loop = self._loop
        if self._sock is None or loop is None:
            self._drop_socket()
            return
        client = self._client
        client.disconnect()
        deadline = loop.time() + timeout
        # paho closes the socket once DISCONNECT is written; give the writer a few turns.
        while self._sock is not None and loop.time() < deadline:  # noqa: ASYNC110 - paho's socket has no event
            await asyncio.sleep(0.01)
        self._drop_socket()

    def close(self) -> None:
        """Drop the connection at once, without DISCONNECT (the broker will publish the will)."""
        self._closed = True
        self._drop_socket()


def _zero() -> int:
    return 0


def _resolve(fut: asyncio.Future[BaseException | None], error: BaseException | None) -> None:
    if not fut.done():
        fut.set_result(error)


def _close_quietly(sock: Any) -> None:
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.close()


def _reason_text(reason: Any) -> str:
    name = getattr(reason, "getName", None)
    text = name() if callable(name) else str(reason)
    return text[0].lower() + text[1:] if text else "unknown reason"


def _translate(exc: BaseException, s: BrokerSettings) -> BrokerError:
    where = s.address
    if isinstance(exc, ssl.SSLCertVerificationError):
        return BrokerError(f"TLS to {where}: the broker's certificate is not trusted ({exc.verify_message})")
    if isinstance(exc, ssl.CertificateError):
        return BrokerError(f"TLS to {where}: {exc}")
    if isinstance(exc, ssl.SSLError):
        return BrokerError(f"TLS handshake with {where} failed: {exc.reason or exc}")
    if isinstance(exc, socket.gaierror):
        return BrokerError(f"cannot resolve the broker host {s.host!r}: {exc.strerror}")
    if isinstance(exc, ConnectionRefusedError):
        return BrokerError(f"{where} refused the TCP connection (is the broker running?)")
    if isinstance(exc, (TimeoutError, socket.timeout)):
        return BrokerError(f"{where} did not answer within {s.connect_timeout:g} s")
    if isinstance(exc, OSError):
        return BrokerError(f"cannot connect to {where}: {exc.strerror or exc}")
    if isinstance(exc, ValueError):
        return BrokerError(f"cannot connect to {where}: {exc}")
    return BrokerError(f"cannot connect to {where}: {type(exc).__name__}: {exc}")
