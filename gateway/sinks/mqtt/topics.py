"""Topic names: `<prefix>/<machine>/<path in lower-case segments>`, and the gateway's own topics.

Pure functions, no I/O. Segments are lower-cased so that topics read the same
way whatever case the controller's programmer liked; characters that MQTT gives
a meaning to (`+`, `#`, `/` inside a segment) or that tools choke on (NUL,
white space) become `_`. Lower-casing can make two paths meet on one topic, so
`plan_topics` checks the whole set at once and names both variables.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from gateway.errors import SinkError

_UNSAFE = re.compile(r"[+#/\x00\s]")
MAX_TOPIC_BYTES = 65535

SET = "set"
RESULT = "result"
STATUS = "status"


class TopicClash(SinkError):
    """Two variables (or a variable and a gateway topic) would publish to the same topic."""


def clean_segment(segment: str) -> str:
    """One topic level from one path segment: lower-case, MQTT-unsafe characters replaced by '_'."""
    cleaned = _UNSAFE.sub("_", segment.lower())
    return cleaned or "_"


def path_topic(path: str) -> str:
    """A tree path as topic levels: `Axes/X/Position` → `axes/x/position`."""
    return "/".join(clean_segment(s) for s in path.split("/"))


def machine_root(prefix: str, machine: str) -> str:
    return f"{prefix}/{clean_segment(machine)}"


def variable_topic(prefix: str, machine: str, path: str, override: str | None = None) -> str:
    """The topic a variable's values go to; `override` replaces the path part, verbatim."""
    return f"{machine_root(prefix, machine)}/{override if override is not None else path_topic(path)}"


def event_topic(prefix: str, machine: str | None, channel: str) -> str:
    """Where an event goes: `<prefix>/<machine>/<channel>` (channel case kept: it may hold ids)."""
    levels = "/".join(_UNSAFE.sub("_", s) or "_" for s in channel.split("/"))
    return f"{machine_root(prefix, machine)}/{levels}" if machine else f"{prefix}/{levels}"


def gateway_status_topic(prefix: str, shard: int | None = None) -> str:
    """`<prefix>/status`; shard K of a fleet: `<prefix>/status/shard-K` (each shard its own, its will too)."""
    return f"{prefix}/{STATUS}" + (f"/shard-{shard}" if shard is not None else "")


def machine_status_topic(prefix: str, machine: str) -> str:
    return f"{machine_root(prefix, machine)}/{STATUS}"


def set_topic(topic: str) -> str:
    return f"{topic}/{SET}"


def result_topic(topic: str) -> str:
    """Where the answer to a write on `topic`/set goes."""
    return f"{topic}/{SET}/{RESULT}"


def target_of_set(topic: str) -> str | None:
    """`cnc/m/feed/override/set` → `cnc/m/feed/override`; None for anything that is not a write request."""
    head, sep, last = topic.rpartition("/")
    if not sep or last != SET or not head:
        return None
    return head


def set_filters(prefix: str, depths: Iterable[int]) -> list[str]:
    """Subscription filters that catch `<prefix>/<machine>/<depth levels>/set` for each depth.

    One filter per depth rather than `<prefix>/#`, so that the gateway does not
    receive its own value stream back (MQTT 3.1.1 has no "no local" option).
    """
    return [f"{prefix}/+/{'+/' * depth}{SET}" for depth in sorted(set(depths)) if depth >= 1]


def topic_depth(topic: str, prefix: str) -> int:
    """How many levels a topic has below `<prefix>/<machine>/`."""
    return topic.count("/") - prefix.count("/") - 1


def valid_publish_topic(topic: str) -> bool:
    """Whether a client-supplied topic (an MQTT v5 response topic) may be published to."""
    if not topic or "+" in topic or "#" in topic or "\x00" in topic:
        return False
    return len(topic.encode("utf-8", "surrogatepass")) <= MAX_TOPIC_BYTES


def topic_matches(topic_filter: str, topic: str) -> bool:
    """Whether `topic` matches an MQTT topic filter: `+` one level, `#` this level and all below (so
    `replies/#` matches `replies` too); wildcards at the first level never match a `$` topic."""
    if topic.startswith("$") and topic_filter[:1] in ("+", "#"):
        return False
    wanted, levels = topic_filter.split("/"), topic.split("/")
    for index, level in enumerate(wanted):
        if level == "#":
            return True
        if index >= len(levels) or (level != "+" and level != levels[index]):
            return False
    return len(wanted) == len(levels)


class ResponseTopics:
    """Where an MQTT 5 request may have its answer published: a result topic (`…/<result_suffix>`) under
    the gateway's prefix, or a topic the gateway file's `mqtt.response_topics` filters allow.

    The gateway publishes answers with its own broker credentials, so a topic the requester names
    elsewhere would let anyone who may publish a request make the gateway publish anywhere its ACL
    reaches (another edge node's command topic, say). Such a request is refused."""

    def __init__(self, prefix: str, allowed: Iterable[str] = ()) -> None:
        self.own = prefix + "/"
        self.allowed = tuple(allowed)

    def refusal(self, requested: str, result_suffix: str) -> str | None:
        """Why `requested` may not be answered on, or None when it may."""
        shown = requested[:200]
        if not valid_publish_topic(requested):
            return f"the response topic {shown!r} is not a topic one can publish to"
        if requested.startswith(self.own):
            if requested.endswith(result_suffix):
                return None
            return (
                f"the response topic {shown!r} is under the gateway's prefix but not a result topic "
                f"(…{result_suffix})"
            )
        if any(topic_matches(f, requested) for f in self.allowed):
            return None
        return (
            f"the response topic {shown!r} is outside the gateway's prefix {self.own[:-1]!r} and not in "
            "mqtt.response_topics"
        )


def plan_topics(
    entries: Iterable[tuple[object, str, str]], reserved: Iterable[str] = ()
) -> dict[object, str]:
    """Map keys to topics, refusing any topic claimed twice.

    `entries` are (key, topic, who) where `who` names the claimant in the error
    (for example `laser-sim/Axes/X/Position`); `reserved` are the gateway's own
    topics (status), which no variable may take.
    """
    owners: dict[str, str] = dict.fromkeys(reserved, "the gateway's status topic")
    out: dict[object, str] = {}
    for key, topic, who in entries:
        if len(topic.encode("utf-8")) > MAX_TOPIC_BYTES:
            raise TopicClash(f"{who}: topic {topic[:60]!r}… is longer than MQTT allows")
        first = owners.get(topic)
        if first is not None:
            raise TopicClash(
                f"{who} and {first} would both publish to {topic!r}; give one of them an mqtt.topic"
            )
        owners[topic] = who
        out[key] = topic
    return out
