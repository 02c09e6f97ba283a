"""Helpers shared by the hardware-link tests: harness field tokens and hypothesis strategies."""

from __future__ import annotations

import struct
from dataclasses import fields

from hypothesis import strategies as st

from gripper_env.hardware import protocol as proto


def f32_token(value: float) -> str:
    """The harness's text form of a float32 field: its bits as 8 hex digits."""
    return f"{struct.unpack('<I', struct.pack('<f', value))[0]:08x}"


def field_tokens(msg: proto.Message) -> list[str]:
    """A message's fields in the harness's dump order (the dataclass field order)."""
    if isinstance(msg, proto.ProfileChunk):
        return [str(v) for v in (msg.start_index, msg.total_length, len(msg.samples_cdeg))] + [
            str(v) for v in msg.samples_cdeg
        ]
    if isinstance(msg, proto.Telemetry):
        out = [str(msg.t0_us), str(msg.decimation), str(len(msg.samples))]
        for s in msg.samples:
            out += [str(s.reference_cdeg), str(s.command_cdeg), str(s.adc), str(s.flags)]
        return out
    values = [getattr(msg, f.name) for f in fields(msg)]
    return [
        f32_token(v) if code == "f" else str(v)
        for code, v in zip(msg._FORMAT, values, strict=True)  # type: ignore[attr-defined]
    ]


_INT_CODES = {"B": (0, 0xFF), "b": (-0x80, 0x7F), "H": (0, 0xFFFF), "h": (-0x8000, 0x7FFF)}
_INT_CODES["I"] = (0, 0xFFFFFFFF)


def field_strategy(code: str) -> st.SearchStrategy:
    """Any value of a wire field type; float32 fields include NaN, infinities and extremes."""
    if code == "f":
        return st.floats(width=32)
    lo, hi = _INT_CODES[code]
    return st.integers(lo, hi)


def fixed_message(cls: type) -> st.SearchStrategy:
    return st.builds(cls, *[field_strategy(code) for code in cls._FORMAT])


samples = st.builds(
    proto.TelemetrySample,
    st.integers(-0x8000, 0x7FFF),
    st.integers(-0x8000, 0x7FFF),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFF),
)

messages = st.one_of(
    *[
        fixed_message(cls)
        for cls in proto.MESSAGE_TYPES.values()
        if cls not in (proto.ProfileChunk, proto.Telemetry)
    ],
    st.builds(
        proto.ProfileChunk,
        st.integers(0, 0xFFFF),
        st.integers(0, 0xFFFF),
        st.lists(
            st.integers(-0x8000, 0x7FFF), min_size=1, max_size=proto.PROFILE_CHUNK_MAX_SAMPLES
        ).map(tuple),
    ),
    st.builds(
        proto.Telemetry,
        st.integers(0, 0xFFFFFFFF),
        st.integers(0, 0xFFFF),
        st.lists(samples, min_size=1, max_size=proto.TELEMETRY_MAX_SAMPLES).map(tuple),
    ),
)
