"""The host's record of the commands it sent: :class:`CommandLog`.

The board numbers nothing it receives, but it sees the host's sequence numbers: when a frame
arrives after a gap it reports the missing ones at once (ERROR ``FRAMES_LOST``, ``seq`` the first
missing, ``detail`` how many). The log keeps the last 256 frames sent by sequence number, so such
a report names commands, and says what to do about each:

=================  ====================================================================
lost frame         what the host does
=================  ====================================================================
SETPOINT           sent again if it is still the latest setpoint, else superseded (the
                   50 Hz stream of a run sends a newer one every 20 ms)
ESTOP              sent again
a request          sent again by the request that waits for its answer
                   (:meth:`GripperDevice._request <gripper_env.hardware.host.device.
                   GripperDevice._request>`)
HEARTBEAT          nothing: any frame that arrived after it fed the watchdog
=================  ====================================================================

Every lost command is counted (:attr:`CommandLog.lost`), and so is each one sent again
(:attr:`CommandLog.resent`) or superseded (:attr:`CommandLog.superseded`).
"""

from __future__ import annotations

from gripper_env.hardware import protocol as proto

__all__ = ["CommandLog", "lost_sequence"]


def lost_sequence(report: proto.ErrorReport) -> list[int]:
    """The sequence numbers a FRAMES_LOST report names (``[]`` for any other report)."""
    if report.code != proto.ErrorCode.FRAMES_LOST:
        return []
    return [(report.seq + k) & 0xFF for k in range(report.detail)]


class CommandLog:
    """The frames the host sent lately, by sequence number, and the board's loss reports.

    Attributes
    ----------
    lost : int
        Host frames the board reported missing.
    resent : int
        Of those, the commands sent again (setpoints still current, ESTOPs).
    superseded : int
        Lost setpoints a newer one had already replaced.
    latest_setpoint : Setpoint or None
        The last SETPOINT sent in this session.
    """

    def __init__(self) -> None:
        self._sent: dict[int, proto.Message] = {}
        self._latest_setpoint_seq: int | None = None
        self.latest_setpoint: proto.Setpoint | None = None
        self.lost = self.resent = self.superseded = 0

    def new_session(self) -> None:
        """A HELLO started a new session: the board holds no setpoint any more."""
        self._latest_setpoint_seq = None
        self.latest_setpoint = None

    def sent(self, seq: int, msg: proto.Message) -> None:
        """Record that ``msg`` went out with sequence number ``seq``."""
        self._sent[seq] = msg
        if isinstance(msg, proto.Setpoint):
            self._latest_setpoint_seq = seq
            self.latest_setpoint = msg

    def to_resend(self, report: proto.ErrorReport) -> list[proto.Message]:
        """Count the frames a FRAMES_LOST report names; return the commands to send again."""
        out: list[proto.Message] = []
        for seq in lost_sequence(report):
            self.lost += 1
            msg = self._sent.pop(seq, None)
            if isinstance(msg, proto.Setpoint):
                if seq == self._latest_setpoint_seq:
                    out.append(msg)
                else:
                    self.superseded += 1
            elif isinstance(msg, proto.Estop):
                out.append(msg)
        self.resent += len(out)
        return out
