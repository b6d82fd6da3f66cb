"""rosbag2 Jazzy metadata: ``metadata.yaml`` (version 9) and the QoS strings of the channels,
field names, order and forms as rosbag2_storage's ``yaml.hpp``/``qos.cpp`` write them
(docs/bag-format.md, "QoS strings" and "metadata.yaml")."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import yaml

VERSION = 9     #: rosbag2 metadata version written by Jazzy

ROS_DISTRO = 'jazzy'
STORAGE_IDENTIFIER = 'mcap'
SERIALIZATION_FORMAT = 'cdr'

INFINITE = {'sec': 9223372036, 'nsec': 854775807}    #: ``RMW_DURATION_INFINITE`` in rosbag2

RELIABILITIES = ('reliable', 'best_effort')


def qos_profile(reliability: str = 'reliable', depth: int = 10) -> dict[str, Any]:
    """Return one offered QoS profile in rosbag2's version-9 form (a keep-last, volatile
    publisher)."""
    if reliability not in RELIABILITIES:
        raise ValueError(f"reliability '{reliability}' is not one of {RELIABILITIES}")
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
        raise ValueError(f'QoS depth {depth!r} is not an int >= 1')
    return {'history': 'keep_last', 'depth': depth, 'reliability': reliability,
            'durability': 'volatile', 'deadline': dict(INFINITE), 'lifespan': dict(INFINITE),
            'liveliness': 'automatic', 'liveliness_lease_duration': dict(INFINITE),
            'avoid_ros_namespace_conventions': False}


class _Dumper(yaml.SafeDumper):
    """Block style like yaml-cpp: nested lists indented, multi-line strings as ``|``."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        super().increase_indent(flow, False)


def _str(dumper: yaml.SafeDumper, data: str) -> yaml.Node:
    style = '|' if '\n' in data else None
    return dumper.represent_scalar('tag:yaml.org,2002:str', data, style=style)


_Dumper.add_representer(str, _str)


def dump_yaml(data: Any) -> str:
    """Dump ``data`` as block-style YAML, keys in insertion order."""
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True, width=100)


def channel_metadata(profiles: list[dict[str, Any]], type_hash: str) -> dict[str, str]:
    """Return a channel's MCAP metadata: its QoS ``profiles`` (no trailing newline, as
    yaml-cpp) and its type hash."""
    return {'offered_qos_profiles': dump_yaml(profiles).rstrip('\n') if profiles else '',
            'topic_type_hash': type_hash}


def load_qos_profiles(text: str) -> list[dict[str, Any]]:
    """Parse a channel's ``offered_qos_profiles`` string back into a list."""
    loaded = yaml.safe_load(text) if text else []
    return loaded if isinstance(loaded, list) else []


@dataclass
class TopicRecord:
    """What metadata.yaml says about one topic; ``message_count`` grows while recording."""

    name: str
    msg_type: str
    qos_profiles: list[dict[str, Any]]
    type_hash: str
    message_count: int = 0


@dataclass
class BagSummary:
    """The numbers metadata.yaml needs; kept up to date by the writer and by recovery."""

    file_name: str
    topics: list[TopicRecord] = field(default_factory=list)
    start_ns: int | None = None
    end_ns: int | None = None

    @property
    def message_count(self) -> int:
        return sum(t.message_count for t in self.topics)

    def add_stamp(self, stamp_ns: int) -> None:
        self.start_ns = stamp_ns if self.start_ns is None else min(self.start_ns, stamp_ns)
        self.end_ns = stamp_ns if self.end_ns is None else max(self.end_ns, stamp_ns)


def bag_information(summary: BagSummary, custom_data: dict[str, str]) -> dict[str, Any]:
    """Return the content of ``rosbag2_bagfile_information`` (also the MCAP metadata record)."""
    start = summary.start_ns or 0
    duration = (summary.end_ns - summary.start_ns) if summary.start_ns is not None else 0
    count = summary.message_count
    return {
        'version': VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msg_type,
                                'serialization_format': SERIALIZATION_FORMAT,
                                'offered_qos_profiles': t.qos_profiles,
                                'type_description_hash': t.type_hash},
             'message_count': t.message_count}
            for t in summary.topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [summary.file_name],
        'files': [{'path': summary.file_name,
                   'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': dict(custom_data),
        'ros_distro': ROS_DISTRO,
    }


def metadata_yaml(summary: BagSummary, custom_data: dict[str, str]) -> str:
    """Return the text of ``metadata.yaml``."""
    return dump_yaml({'rosbag2_bagfile_information': bag_information(summary, custom_data)})
