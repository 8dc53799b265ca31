"""Which topics of a ROS bag the reader uses (:func:`choose_topic`): pure, over the bag's topic list.

Message types are named the ROS 2 way (``sensor_msgs/msg/LaserScan``); ``rosbags`` names ROS 1 types so too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from shared.io.errors import RosbagTopicError

__all__ = ["LASER_SCAN_TYPE", "ODOMETRY_TYPE", "TF_TYPES", "choose_topic"]

LASER_SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
#: tf message types: ROS 2 / ROS 1 tf2 and ROS 1 tf.
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
#: The odometry topic REP 105 names, preferred when a bag has several.
PREFERRED_ODOMETRY = "/odom"


def choose_topic(
    bag: str,
    topics: Mapping[str, str],
    wanted: str | None,
    types: Sequence[str],
    option: str,
    *,
    required: bool,
) -> str | None:
    """The topic to read among ``topics`` (name -> message type) of one of ``types``.

    ``wanted`` (the leading ``/`` may be left out) must exist and carry one of ``types``; without it, the
    only candidate, else (when not ``required``) :data:`PREFERRED_ODOMETRY` if among them. No candidate
    gives ``None`` unless ``required``. Raises :class:`RosbagTopicError` naming ``bag``, the candidates and
    ``option`` (how the caller chooses). O(topics log topics).
    """
    candidates = tuple(sorted(t for t, ty in topics.items() if ty in types))
    kind = types[0]
    listed = ", ".join(candidates) or "none"
    if wanted is not None:
        name = wanted if wanted in topics else "/" + wanted.lstrip("/")
        if name not in topics:
            raise RosbagTopicError(
                f"{bag}: no topic {wanted!r}: {kind} topics in the bag: {listed}", candidates
            )
        if topics[name] not in types:
            raise RosbagTopicError(
                f"{bag}: topic {name} carries {topics[name]}: expected {kind} ({kind} topics in the bag: "
                f"{listed})",
                candidates,
            )
        return name
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        if not required:
            return None
        everything = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
        raise RosbagTopicError(f"{bag}: no {kind} topic: topics in the bag: {everything}")
    if not required and PREFERRED_ODOMETRY in candidates:
        return PREFERRED_ODOMETRY
    raise RosbagTopicError(
        f"{bag}: {len(candidates)} {kind} topics ({listed}): choose one with {option}", candidates
    )
