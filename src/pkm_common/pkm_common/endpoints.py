"""A node's publishers and subscriptions on the graph's topics, from the one catalogue
(pkm_common.topics: name, message type, QoS kind) instead of literals in each node:
``publisher(node, topics.DRIVES_COMMAND)``, ``subscription(node, topics.ESTOP, callback)``.
A publisher offers ``qos.publisher_qos`` (the per-step streams' deeper history), a
subscription asks for ``qos.TOPIC_QOS``.
"""

from __future__ import annotations

import importlib
import re

from rclpy.qos import qos_profile_system_default

from pkm_common.qos import TOPIC_QOS, publisher_qos
from pkm_common.topics import CATALOGUE

__all__ = ["message_class", "publisher", "subscription", "topic_message_class", "system_publisher",
           "system_subscription"]

_MSGTYPE = re.compile(r"[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*")


def message_class(msgtype: str):
    """'sensor_msgs/msg/JointState' -> the rclpy message class; ValueError for a
    string that is not a message type name (nothing else is imported)."""
    if not isinstance(msgtype, str) or not _MSGTYPE.fullmatch(msgtype):
        raise ValueError(f"{msgtype!r} is not a message type name (package/msg/Name)")
    package, _, name = msgtype.rpartition("/")
    return getattr(importlib.import_module(package.replace("/", ".")), name)


def topic_message_class(topic: str):
    """The message class of a catalogue topic; KeyError naming the topic otherwise."""
    try:
        return message_class(CATALOGUE[topic].type)
    except KeyError:
        raise KeyError(f"topic {topic!r} is not in pkm_common.topics.CATALOGUE") from None


def publisher(node, topic: str):
    """``node``'s publisher of the catalogue ``topic`` (its type, its publisher QoS)."""
    return node.create_publisher(topic_message_class(topic), topic, publisher_qos(topic))


def subscription(node, topic: str, callback, raw: bool = False, **kwargs):
    """``node``'s subscription to the catalogue ``topic`` (its type and QoS);
    ``raw``: the callback takes the serialized bytes (pkm_common.cdr decodes them);
    ``kwargs`` go to ``create_subscription`` (event_callbacks)."""
    return node.create_subscription(topic_message_class(topic), topic, callback, TOPIC_QOS[topic], raw=raw,
                                    **kwargs)


def system_publisher(node, msg_class, name: str):
    """A publisher on a topic of another system, not of the graph's catalogue (a
    ros2_control system's controller commands, named by the machine file), with the
    QoS ROS 2's own nodes use there: the system default (rclcpp::SystemDefaultsQoS: reliable,
    volatile, and the RMW's own history: Fast DDS keeps the newest sample only, so a
    reader that falls a period behind gets the newest, not a queue)."""
    return node.create_publisher(msg_class, name, qos_profile_system_default)


def system_subscription(node, msg_class, name: str, callback):
    """A subscription to a topic of another system (``system_publisher``'s QoS): a
    ros2_control system's joint_states."""
    return node.create_subscription(msg_class, name, callback, qos_profile_system_default)
