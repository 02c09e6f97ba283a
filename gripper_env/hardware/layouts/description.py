"""The protocol's description, ``firmware/protocol.toml``: its model and its loading."""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "CONST_TYPES",
    "DESCRIPTION",
    "FIRMWARE",
    "HEADER",
    "PROTOCOL_MD",
    "WIRE_TYPES",
    "Array",
    "Description",
    "Enum",
    "Field",
    "LayoutError",
    "Member",
    "Message",
    "field_offsets",
    "load_description",
]

FIRMWARE = Path(__file__).resolve().parents[3] / "firmware"
DESCRIPTION = FIRMWARE / "protocol.toml"
HEADER = FIRMWARE / "gripper" / "gripper_messages.h"
PROTOCOL_MD = FIRMWARE / "PROTOCOL.md"

# wire type -> (C++ type, struct format char, size, put/get suffix)
WIRE_TYPES = {
    "u8": ("uint8_t", "B", 1, "u8"),
    "i8": ("int8_t", "b", 1, "i8"),
    "u16": ("uint16_t", "H", 2, "u16"),
    "i16": ("int16_t", "h", 2, "i16"),
    "u32": ("uint32_t", "I", 4, "u32"),
    "f32": ("float", "f", 4, "f32"),
}
_CODEC_NAMES = {"b", "len", "e", "c", "k", "TYPE", "SIZE", "HEADER", "ENTRY_SIZE"}
CONST_TYPES = {"u8": "uint8_t", "u16": "uint16_t", "i16": "int16_t", "size": "size_t"}


class LayoutError(ValueError):
    """The description is malformed; the message names the key."""


@dataclass(frozen=True)
class Field:
    """One wire field: ``name``, wire ``type`` (u8 ... f32) and its ``doc`` (unit, rule)."""

    name: str
    type: str
    doc: str = ""


@dataclass(frozen=True)
class Array:
    """Entries after a message's fixed fields: ``of`` a wire type or a struct name, ``min`` to
    ``max`` of them, counted by the field ``count`` or implied by the payload length."""

    name: str
    of: str
    min: int
    max: str | int
    count: str | None = None
    doc: str = ""


@dataclass(frozen=True)
class Message:
    """A message layout."""

    key: str
    id: int
    cpp: str
    python: str
    fields: tuple[Field, ...]
    array: Array | None = None
    field_enum: str | None = None

    @property
    def to_device(self) -> bool:
        """Host -> device (ids below 0x80)."""
        return self.id < 0x80

    @property
    def size(self) -> int:
        """Bytes of the fixed fields (the whole payload if there is no array)."""
        return sum(WIRE_TYPES[f.type][2] for f in self.fields)

    @property
    def format(self) -> str:
        """:mod:`struct` format characters of the fixed fields."""
        return "".join(WIRE_TYPES[f.type][1] for f in self.fields)


@dataclass(frozen=True)
class Member:
    name: str
    value: int
    doc: str = ""
    detail: str = ""


@dataclass(frozen=True)
class Enum:
    name: str
    python: str
    prefix: str
    doc: str
    members: tuple[Member, ...]
    bits: bool = False


@dataclass(frozen=True)
class Description:
    """Everything in ``protocol.toml``."""

    constants: dict[str, tuple[int, str, str]]  # name -> (value, type, doc)
    enums: dict[str, Enum]
    structs: dict[str, tuple[str, tuple[Field, ...]]]  # name -> (python name, fields)
    messages: dict[str, Message]

    def array_size(self, array: Array) -> int:
        """Bytes of one array entry."""
        if array.of in WIRE_TYPES:
            return WIRE_TYPES[array.of][2]
        return sum(WIRE_TYPES[f.type][2] for f in self.structs[array.of][1])

    def array_max(self, array: Array) -> int:
        return array.max if isinstance(array.max, int) else self.constants[array.max][0]


# ---- loading -------------------------------------------------------------------------------------


def _fields(items: Any, where: str) -> tuple[Field, ...]:
    if not isinstance(items, list):
        raise LayoutError(f"{where}: 'fields' must be a list")
    out = []
    for k, item in enumerate(items):
        try:
            f = Field(**item)
        except TypeError as exc:
            raise LayoutError(f"{where}.fields[{k}]: {exc}") from None
        if f.type not in WIRE_TYPES:
            raise LayoutError(
                f"{where}.fields[{k}] ({f.name}): unknown wire type {f.type!r}; "
                f"use one of {', '.join(WIRE_TYPES)}"
            )
        out.append(f)
    names = [f.name for f in out]
    clash = set(names) & _CODEC_NAMES
    if clash:
        raise LayoutError(f"{where}: field names {sorted(clash)} are the generated codecs' locals")
    if len(set(names)) != len(names):
        raise LayoutError(f"{where}: duplicate field names in {names}")
    return tuple(out)


def load_description(path: str | Path = DESCRIPTION) -> Description:
    """Read and check ``protocol.toml``.

    Raises
    ------
    LayoutError
        A malformed entry, naming the file and the key.
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise LayoutError(f"{path}: {exc}") from None
    try:
        constants = {
            name: (int(c["value"]), str(c["type"]), str(c.get("doc", "")))
            for name, c in raw["constants"].items()
        }
        for name, (_value, typ, _doc) in constants.items():
            if typ not in CONST_TYPES:
                raise LayoutError(
                    f"{path}: constants.{name}: type must be one of {list(CONST_TYPES)}"
                )
        enums = {
            name: Enum(
                name,
                e["python"],
                e["prefix"],
                e.get("doc", ""),
                tuple(Member(**m) for m in e["members"]),
                bool(e.get("bits", False)),
            )
            for name, e in raw["enums"].items()
        }
        structs = {
            name: (s["python"], _fields(s["fields"], f"{path}: structs.{name}"))
            for name, s in raw["structs"].items()
        }
        messages = {}
        for key, m in raw["messages"].items():
            where = f"{path}: messages.{key}"
            array = Array(**m["array"]) if "array" in m else None
            if array is not None and array.of not in WIRE_TYPES and array.of not in structs:
                raise LayoutError(f"{where}.array: 'of' names no wire type or struct: {array.of}")
            messages[key] = Message(
                key,
                int(m["id"]),
                m["cpp"],
                m["python"],
                _fields(m["fields"], where),
                array,
                m.get("field_enum"),
            )
    except KeyError as exc:
        raise LayoutError(f"{path}: missing key {exc}") from None
    except TypeError as exc:
        raise LayoutError(f"{path}: {exc}") from None
    ids = [m.id for m in messages.values()]
    if len(set(ids)) != len(ids):
        raise LayoutError(f"{path}: duplicate message ids {sorted(ids)}")
    return Description(constants, enums, structs, messages)


def field_offsets(flds: Sequence[Field]) -> list[int]:
    """Byte offset of each field in a packed layout."""
    out, at = [], 0
    for f in flds:
        out.append(at)
        at += WIRE_TYPES[f.type][2]
    return out
