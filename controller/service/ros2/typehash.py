"""ROS 2 type names and type hashes (REP 2011 "RIHS01"), computed from message definitions.

rmw_zenoh puts the type hash in every key expression and liveliness token, so a subscriber
only hears a publisher of the same type version. The hash is rosidl's: the type description
(the type's fields and, sorted by name, every type it refers to), without default values, as
`json.dumps(..., separators=(", ", ": "))`, hashed with SHA-256. The definitions below are the
fields of the ROS 2 Jazzy (and later) messages this package speaks; comments and constants are
left out because they are not part of the hash. Pure: no I/O.
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
from typing import Any

MSG_DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "std_msgs/msg/String": "string data",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/msg/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose",
    "geometry_msgs/msg/Twist": "Vector3 linear\nVector3 angular",
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort"
    ),
}
"""The fields of each message, in order, as in its `.msg` file (comments and constants out)."""

# type_description_interfaces/msg/FieldType: primitive ids; +48 fixed array, +96 bounded
# sequence, +144 unbounded sequence.
_FIELD_TYPE_IDS: dict[str, int] = {
    "int8": 2,
    "uint8": 3,
    "int16": 4,
    "uint16": 5,
    "int32": 6,
    "uint32": 7,
    "int64": 8,
    "uint64": 9,
    "float32": 10,
    "float64": 11,
    "char": 13,
    "wchar": 14,
    "bool": 15,
    "byte": 16,
    "string": 17,
    "wstring": 18,
}
_NESTED = 1
_FIXED_ARRAY, _BOUNDED_SEQUENCE, _UNBOUNDED_SEQUENCE = 48, 96, 144
_BOUNDED_STRING, _BOUNDED_WSTRING = 21, 22
_FIELD_RE = re.compile(
    r"^(?P<base>[A-Za-z][\w/]*)(?:<=(?P<strcap>\d+))?(?P<arr>\[(?:<=)?\d*\])?\s+(?P<name>\w+)$"
)


class TypeHashError(ValueError):
    """A message definition this module cannot describe (unknown type, bad field line)."""


def dds_type_name(type_name: str) -> str:
    """The DDS form of a ROS type name, as rmw_zenoh writes it in key expressions:
    `geometry_msgs/msg/PoseStamped` -> `geometry_msgs::msg::dds_::PoseStamped_`.
    Raises TypeHashError for a name that is not `package/msg/Name`."""
    parts = type_name.split("/")
    if len(parts) != 3 or not all(parts):
        raise TypeHashError(f"not a ROS type name package/msg/Name: {type_name!r}")
    pkg, kind, name = parts
    return f"{pkg}::{kind}::dds_::{name}_"


def _field(line: str, package: str) -> tuple[str, dict[str, Any]]:
    """(field name, FieldType dict) of one definition line."""
    m = _FIELD_RE.match(line.strip())
    if m is None:
        raise TypeHashError(f"cannot parse field {line!r}")
    base, arr = m["base"], m["arr"]
    capacity = 0
    string_capacity = int(m["strcap"]) if m["strcap"] else 0
    nested = ""
    if base in _FIELD_TYPE_IDS:
        type_id = _FIELD_TYPE_IDS[base]
        if string_capacity:
            type_id = _BOUNDED_STRING if base == "string" else _BOUNDED_WSTRING
    else:
        pkg, _, name = base.rpartition("/")
        nested = f"{pkg or package}/msg/{name}"
        if nested not in MSG_DEFINITIONS:
            raise TypeHashError(f"unknown type {base!r} in field {line!r}")
        type_id = _NESTED
    if arr:
        inner = arr[1:-1]
        if inner.startswith("<="):
            type_id += _BOUNDED_SEQUENCE
            capacity = int(inner[2:])
        elif inner:
            type_id += _FIXED_ARRAY
            capacity = int(inner)
        else:
            type_id += _UNBOUNDED_SEQUENCE
    return m["name"], {
        "type_id": type_id,
        "capacity": capacity,
        "string_capacity": string_capacity,
        "nested_type_name": nested,
    }


def _individual(type_name: str) -> dict[str, Any]:
    """The IndividualTypeDescription of `type_name` (default values left out)."""
    package = type_name.split("/")[0]
    lines = [x for x in MSG_DEFINITIONS[type_name].splitlines() if x.strip()]
    fields = [{"name": n, "type": t} for n, t in (_field(x, package) for x in lines)]
    return {"type_name": type_name, "fields": fields}


def type_description(type_name: str) -> dict[str, Any]:
    """The TypeDescription of `type_name` as rosidl hashes it: the type and, sorted by name,
    every type it refers to (directly or not). Raises TypeHashError for an unknown type."""
    if type_name not in MSG_DEFINITIONS:
        raise TypeHashError(f"no definition for {type_name!r}")
    main = _individual(type_name)
    seen: dict[str, dict[str, Any]] = {}
    todo = [f["type"]["nested_type_name"] for f in main["fields"]]
    while todo:
        name = todo.pop()
        if not name or name in seen:
            continue
        seen[name] = _individual(name)
        todo.extend(f["type"]["nested_type_name"] for f in seen[name]["fields"])
    return {
        "type_description": main,
        "referenced_type_descriptions": [seen[k] for k in sorted(seen)],
    }


@functools.cache
def type_hash(type_name: str) -> str:
    """The REP 2011 type hash `RIHS01_<sha256 hex>` of `type_name` (one of MSG_DEFINITIONS).
    Raises TypeHashError for an unknown type."""
    text = json.dumps(type_description(type_name), separators=(", ", ": "), ensure_ascii=True)
    return "RIHS01_" + hashlib.sha256(text.encode("utf-8")).hexdigest()
