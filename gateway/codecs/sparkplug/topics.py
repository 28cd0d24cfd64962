"""Sparkplug B topics: `spBv1.0/<group_id>/<message_type>/<edge_node_id>[/<device_id>]`, and STATE.

Sparkplug 3.0 (chapter 4): ids are UTF-8 strings without '+', '/' and '#'; NBIRTH, NDEATH,
NDATA and NCMD carry no device id, DBIRTH, DDEATH, DDATA and DCMD must. A host application's
STATE is `spBv1.0/STATE/<host_id>`; Sparkplug 2.2 hosts used `STATE/<host_id>` (outside the
namespace), which `parse_topic` also reads, marked `legacy`.

Choices where the specification is silent: an empty id is refused (it would make an empty
topic level); so are U+0000 (MQTT forbids it in topics) and a group id of `STATE`, which
would put edge nodes under the hosts' `spBv1.0/STATE/#`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from gateway.codecs.sparkplug.errors import BadId, BadTopic

NAMESPACE = "spBv1.0"
STATE = "STATE"
_RESERVED = ("+", "#", "/", "\x00")
_MAX_TOPIC_BYTES = 65535  # an MQTT UTF-8 string's length field


class MessageType(str, Enum):
    NBIRTH = "NBIRTH"
    NDEATH = "NDEATH"
    NDATA = "NDATA"
    NCMD = "NCMD"
    DBIRTH = "DBIRTH"
    DDEATH = "DDEATH"
    DDATA = "DDATA"
    DCMD = "DCMD"

    @property
    def is_device(self) -> bool:
        """Whether the topic carries a device id."""
        return self.value[0] == "D"

    @property
    def qos(self) -> int:
        """MQTT QoS the specification requires: 1 for NDEATH (the will), 0 for every other."""
        return 1 if self is MessageType.NDEATH else 0

    @property
    def retain(self) -> bool:
        """No edge node message is retained (STATE, a host's, is)."""
        return False


STATE_QOS = 1
STATE_RETAIN = True


@dataclass(frozen=True, slots=True)
class Topic:
    """An edge node's or device's topic."""

    group_id: str
    message_type: MessageType
    edge_node_id: str
    device_id: str | None = None

    def __post_init__(self) -> None:
        check_id("group id", self.group_id)
        if self.group_id == STATE:
            raise BadId(f"group id {STATE!r} is where host applications publish their STATE")
        check_id("edge node id", self.edge_node_id)
        if self.message_type.is_device:
            if self.device_id is None:
                raise BadTopic(f"a {self.message_type.value} topic needs a device id")
            check_id("device id", self.device_id)
        elif self.device_id is not None:
            raise BadTopic(f"a {self.message_type.value} topic has no device id")

    def __str__(self) -> str:
        parts = [NAMESPACE, self.group_id, self.message_type.value, self.edge_node_id]
        if self.device_id is not None:
            parts.append(self.device_id)
        return "/".join(parts)


@dataclass(frozen=True, slots=True)
class StateTopic:
    """A host application's STATE topic; `legacy` for Sparkplug 2.2's `STATE/<host_id>`."""

    host_id: str
    legacy: bool = False

    def __post_init__(self) -> None:
        check_id("host id", self.host_id)

    def __str__(self) -> str:
        if self.legacy:
            return f"{STATE}/{self.host_id}"
        return f"{NAMESPACE}/{STATE}/{self.host_id}"


def check_id(what: str, value: str) -> str:
    """Return `value` if it may be a Sparkplug topic level, else raise BadId saying why."""
    if not isinstance(value, str):
        raise BadId(f"{what} must be text, got {type(value).__name__}")
    if not value:
        raise BadId(f"{what} is empty")
    for char in _RESERVED:
        if char in value:
            shown = "U+0000" if char == "\x00" else repr(char)
            raise BadId(f"{what} {value!r} contains {shown}, which Sparkplug reserves")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise BadId(f"{what} {value!r} is not valid UTF-8 text") from None
    return value


def node_topic(group_id: str, message_type: MessageType, edge_node_id: str) -> str:
    return str(Topic(group_id, message_type, edge_node_id))


def device_topic(group_id: str, message_type: MessageType, edge_node_id: str, device_id: str) -> str:
    return str(Topic(group_id, message_type, edge_node_id, device_id))


def state_topic(host_id: str) -> str:
    """The Sparkplug 3.0 STATE topic of a primary host application."""
    return str(StateTopic(host_id))


def command_subscriptions(group_id: str, edge_node_id: str) -> tuple[str, str]:
    """What an edge node subscribes to for its commands: its NCMD and every device's DCMD."""
    ncmd = node_topic(group_id, MessageType.NCMD, edge_node_id)
    dcmd = f"{NAMESPACE}/{group_id}/{MessageType.DCMD.value}/{edge_node_id}/+"
    return ncmd, dcmd


def parse_topic(text: str) -> Topic | StateTopic:
    """Read a topic the edge node received (or published); BadTopic/BadId if it is not Sparkplug B."""
    if len(text.encode("utf-8", "surrogatepass")) > _MAX_TOPIC_BYTES:
        raise BadTopic("longer than an MQTT topic can be")
    parts = text.split("/")
    if parts[0] == STATE and len(parts) == 2:
        return StateTopic(parts[1], legacy=True)
    if parts[0] != NAMESPACE:
        raise BadTopic(f"not in the {NAMESPACE} namespace: {text[:80]!r}")
    if len(parts) == 3 and parts[1] == STATE:
        return StateTopic(parts[2])
    if len(parts) not in (4, 5):
        raise BadTopic(
            f"expected {NAMESPACE}/group_id/message_type/edge_node_id[/device_id], "
            f"got {len(parts)} levels: {text[:80]!r}"
        )
    try:
        message_type = MessageType(parts[2])
    except ValueError:
        raise BadTopic(f"unknown message type {parts[2][:40]!r}") from None
    device_id = parts[4] if len(parts) == 5 else None
    return Topic(parts[1], message_type, parts[3], device_id)
