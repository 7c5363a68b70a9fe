"""Every counter fedlab keeps, named once: what one count means, who counts it, and
whether it signals a fault.

An agent's counters are its status line's ``counters`` (``fedlab monitor`` and ``fedlab
ctl`` read them, and so do users' scripts); a bridge's, a serial platform's and a
scenario's go into the same line, the emulated device's into ``fedlab emulate-device``'s
exit line. Every one of them is a :class:`Count`, and one table, :data:`ROWS`, says for
each

- what one count means,
- who counts it (:class:`Source`: a counter shared by an agent and a bridge means the
  same on both), and
- whether it signals a fault (``fault``: an input refused or lost, an error, a hold;
  worth a look when it grows), or is the traffic of a healthy run.

``docs/counters.md`` is written from it (``fedlab schemas --counters``). The rules:

1. A counter is named by its :class:`Count` member, never by a bare string: a call site
   says ``count(Count.POSE_RECEIVED)``, a dict of counters is keyed by members.
   ``tests/unit/core/test_counters.py`` scans the library for counters named otherwise.
2. A member's value is the counter's name in the status JSON, a public interface: it
   never changes. A :class:`Count` is a ``str``, so a dict keyed by members is the same
   JSON as one keyed by their values, and ``counters["pose_received"]`` finds it.
3. Every member has one row in :data:`ROWS`, and no two members share a value.
4. A count is one event; counters only grow while the process lives, except the
   ``recording_*`` ones, which describe the run being recorded now.

Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = ["BY_COUNT", "ROWS", "Count", "CountRow", "Source", "counters_table_markdown"]


class Source(StrEnum):
    """Who counts: the part of fedlab whose status (or exit line) carries the counter."""

    AGENT = "agent"
    """Every agent's runtime: its intake, sync links, commands, watches, loop, status."""
    RECORDING = "run recording"
    GNC = "GNC chain"
    """Every platform's chain (simulated, serial)."""
    SERIAL = "serial platform"
    SCENARIO = "scenario"
    UDP_BRIDGE = "UDP bridge"
    ROS2_BRIDGE = "ROS 2 bridge"
    """``fedlab ros2``: its forwarder (logged) and a joined platform's agent (status)."""
    DEVICE = "emulated device"
    """``fedlab emulate-device`` (its exit line)."""


class Count(StrEnum):
    """A counter. Its value is its name in ``status.counters``: never changed."""

    # -- an agent's runtime: poses -------------------------------------------------------
    POSE_RECEIVED = "pose_received"
    POSE_OVERSIZED = "pose_oversized"
    POSE_MALFORMED = "pose_malformed"
    POSE_STAMP_MALFORMED = "pose_stamp_malformed"
    POSE_OTHER_REFERENCE = "pose_other_reference"
    POSE_STALE_DROPPED = "pose_stale_dropped"
    POSE_OUT_OF_ORDER = "pose_out_of_order"
    POSE_WITHHELD_NO_FIX = "pose_withheld_no_fix"
    POSE_NOT_FINITE = "pose_not_finite"
    CONTESTED = "contested"
    CONTESTED_DROPPED = "contested_dropped"
    # -- sync ----------------------------------------------------------------------------
    SYNC_REQUESTS_SERVED = "sync_requests_served"
    SYNC_REQUESTS_MALFORMED = "sync_requests_malformed"
    SYNC_REQUESTS_OVERSIZED = "sync_requests_oversized"
    SYNC_REPLY_ERRORS = "sync_reply_errors"
    SYNC_REPLIES_OVERSIZED = "sync_replies_oversized"
    SYNC_ATTACHMENT_MALFORMED = "sync_attachment_malformed"
    CLOCK_STEPS = "clock_steps"
    # -- runs ended here -----------------------------------------------------------------
    REFERENCE_RESTARTED = "reference_restarted"
    REFERENCE_CLOCK_STEPS = "reference_clock_steps"
    ROUTER_LOST = "router_lost"
    FIX_RESTART = "fix_restart"
    # -- holds ---------------------------------------------------------------------------
    NAME_TAKEN_HOLDS = "name_taken_holds"
    STALE_HOLDS = "stale_holds"
    CONTESTED_HOLDS = "contested_holds"
    NO_ROUTER_HOLDS = "no_router_holds"
    FIX_RESTART_HOLDS = "fix_restart_holds"
    HOLDS_RESTORED = "holds_restored"
    SILENT_PEER_ALARMS = "silent_peer_alarms"
    # -- commands ------------------------------------------------------------------------
    CONTROL_RECEIVED = "control_received"
    CONTROL_MALFORMED = "control_malformed"
    COMMANDS_REPEATED = "commands_repeated"
    COMMANDS_DROPPED = "commands_dropped"
    COMMANDS_IGNORED = "commands_ignored"
    # -- the loop and the status line ----------------------------------------------------
    LOOP_OVERRUNS = "loop_overruns"
    STATUS_WRITE_ERRORS = "status_write_errors"
    # -- the run's recording -------------------------------------------------------------
    RECORDING_DROPPED_OVER_BUDGET = "recording_dropped_over_budget"
    RECORDING_DROPPED_QUEUE_FULL = "recording_dropped_queue_full"
    RECORDING_WRITE_ERRORS = "recording_write_errors"
    # -- the GNC chain: control steps closed, per reason (agents.gnc.Reason) -------------
    CLOSED_HELD = "closed_held"
    CLOSED_NO_FIX = "closed_no_fix"
    CLOSED_DEVICE_RESTART = "closed_device_restart"
    CLOSED_FIX_RESTART = "closed_fix_restart"
    CLOSED_FIX_REJECTED = "closed_fix_rejected"
    CLOSED_STALE_FIX = "closed_stale_fix"
    CLOSED_STALE_IMU = "closed_stale_imu"
    CLOSED_SETTLING = "closed_settling"
    CLOSED_NONFINITE = "closed_nonfinite"
    # -- the GNC chain: sensor data and estimates ----------------------------------------
    IMU_REJECTED = "imu_rejected"
    FIX_REJECTED = "fix_rejected"
    FIX_OUTSIDE = "fix_outside"
    FIX_OUTLIER = "fix_outlier"
    FIX_LATE = "fix_late"
    FIX_ACQUIRING = "fix_acquiring"
    FIX_ACQUIRE_RESTARTS = "fix_acquire_restarts"
    FIX_UNCARRIED = "fix_uncarried"
    FIX_RESTARTS = "fix_restarts"
    CLOCK_STEPS_BACK = "clock_steps_back"
    RESTARTS = "restarts"
    # -- the serial platform: the host's side --------------------------------------------
    FRAMES_SENT = "frames_sent"
    WRITE_TIMEOUTS = "write_timeouts"
    WRITE_SHORT = "write_short"
    DEVICE_FAILSAFE_REPORTS = "device_failsafe_reports"
    DEVICE_FRAMES_NOT_NEWER = "device_frames_not_newer"
    DEVICE_FRAMES_OFF_TIMELINE = "device_frames_off_timeline"
    DEVICE_POSE_STALE = "device_pose_stale"
    DEVICE_RESTARTS = "device_restarts"
    # -- the serial platform: its frame decoder (agents.serial.protocol) -----------------
    FRAMES_OK = "frames_ok"
    BAD_CHECKSUM = "bad_checksum"
    GARBAGE_BYTES = "garbage_bytes"
    OVERSIZE = "oversize"
    UNKNOWN_TYPE = "unknown_type"
    BAD_LENGTH = "bad_length"
    BAD_VALUE = "bad_value"
    FRAME_BYTES = "frame_bytes"
    BYTES_IN = "bytes_in"
    # -- scenarios -----------------------------------------------------------------------
    WORKSPACE_CLAMPED = "workspace_clamped"
    WORKSPACE_HOLDS = "workspace_holds"
    RELATIVE_GIVEN = "relative_given"
    RELATIVE_OUT_OF_VIEW = "relative_out_of_view"
    RELATIVE_DROPPED = "relative_dropped"
    RELATIVE_NO_POSE = "relative_no_pose"
    RELATIVE_STALE_POSE = "relative_stale_pose"
    BACKOFFS_CORRIDOR = "backoffs_corridor"
    BACKOFFS_LOST = "backoffs_lost"
    TARGET_JUMPS = "target_jumps"
    MEMBERS_OFF_SLOT = "members_off_slot"
    MEMBERS_TOO_FAST = "members_too_fast"
    # -- the UDP bridge ------------------------------------------------------------------
    UDP_REQUESTS_SENT = "udp_requests_sent"
    UDP_FOREIGN = "udp_foreign"
    UDP_HELD_FOR_NAME = "udp_held_for_name"
    UDP_REQUESTS_FOREIGN_PORT = "udp_requests_foreign_port"
    UDP_REPLIES_FOREIGN_PORT = "udp_replies_foreign_port"
    UDP_MALFORMED = "udp_malformed"
    UDP_SELF = "udp_self"
    UDP_REQUESTS_HELD = "udp_requests_held"
    UDP_REQUESTS_UNSYNCED = "udp_requests_unsynced"
    UDP_REQUESTS_CONTESTED = "udp_requests_contested"
    UDP_REQUESTS_REFERENCE_GONE = "udp_requests_reference_gone"
    UDP_REQUESTS_NO_POSE = "udp_requests_no_pose"
    UDP_REQUESTS_STALE = "udp_requests_stale"
    UDP_RATE_LIMITED = "udp_rate_limited"
    UDP_REQUESTS_SERVED = "udp_requests_served"
    UDP_SEND_ERRORS = "udp_send_errors"
    UDP_RECEIVE_ERRORS = "udp_receive_errors"
    LEGACY_FOUND = "legacy_found"
    LEGACY_LOST = "legacy_lost"
    LEGACY_RESTARTED = "legacy_restarted"
    POSE_UNCONFIRMED = "pose_unconfirmed"
    POSE_PUBLISHED = "pose_published"
    POSE_OTHER_AGENT = "pose_other_agent"
    SYNC_REQUESTS_HELD = "sync_requests_held"
    SYNC_REQUESTS_UNSYNCED = "sync_requests_unsynced"
    SYNC_REPLY_OVERSIZED = "sync_reply_oversized"
    STATUS_NOT_ITS_OWN = "status_not_its_own"
    STATUS_MALFORMED = "status_malformed"
    STATUS_OVERSIZED = "status_oversized"
    CONTROL_OVERSIZED = "control_oversized"
    # -- the ROS 2 bridge ----------------------------------------------------------------
    POSE_FOREIGN_KEY = "pose_foreign_key"
    ODOM_UNMAPPED = "odom_unmapped"
    ODOM_UNWRITABLE = "odom_unwritable"
    ODOM_PUBLISHED = "odom_published"
    TF_PUBLISHED = "tf_published"
    ODOM_RECEIVED = "odom_received"
    ODOM_CONTESTED = "odom_contested"
    ODOM_FOREIGN_FRAME = "odom_foreign_frame"
    ODOM_CLOCK = "odom_clock"
    ODOM_NOT_NEWER = "odom_not_newer"
    ODOM_MALFORMED = "odom_malformed"
    ODOM_STALE_HOLDS = "odom_stale_holds"
    POSE_WITHHELD = "pose_withheld"
    ROS_HOLD_WRITTEN = "ros_hold_written"
    # -- the emulated serial device ------------------------------------------------------
    RX_FRAMES_OK = "rx_frames_ok"
    RX_BAD_CHECKSUM = "rx_bad_checksum"
    RX_GARBAGE_BYTES = "rx_garbage_bytes"
    RX_OVERSIZE = "rx_oversize"
    RX_UNKNOWN_TYPE = "rx_unknown_type"
    RX_BAD_LENGTH = "rx_bad_length"
    RX_BAD_VALUE = "rx_bad_value"
    RX_FRAME_BYTES = "rx_frame_bytes"
    RX_BYTES_IN = "rx_bytes_in"
    FAILSAFE_TRIPS = "failsafe_trips"
    VALVES_IGNORED = "valves_ignored"
    FIXES_UNSEEN = "fixes_unseen"
    INJECTED_GARBAGE_BYTES = "injected_garbage_bytes"
    INJECTED_BAD_CRC = "injected_bad_crc"


@dataclass(frozen=True)
class CountRow:
    """One row of :data:`ROWS`."""

    count: Count
    by: tuple[Source, ...]
    """Who counts it, the first where its meaning is written."""
    fault: bool
    """Whether a count signals a fault (an input refused or lost, an error, a hold)."""
    meaning: str
    """What one count means."""


def _row(count: Count, by: Source | tuple[Source, ...], fault: bool, meaning: str) -> CountRow:
    return CountRow(count, by if isinstance(by, tuple) else (by,), fault, meaning)


C, S = Count, Source
A, U, R = S.AGENT, S.UDP_BRIDGE, S.ROS2_BRIDGE
FAULT, OK = True, False
# fmt: off
ROWS: tuple[CountRow, ...] = (
    # An agent's runtime (a bridge counting the same event names it too).
    _row(C.POSE_RECEIVED, (A, U), OK,
         "a pose sample of another agent read (a bridge: of the agent it follows), used "
         "or not"),
    _row(C.POSE_OVERSIZED, (A, U), FAULT,
         "a pose sample far larger than any pose: dropped unread"),
    _row(C.POSE_MALFORMED, (A, U, R), FAULT,
         "a pose sample that does not decode: dropped"),
    _row(C.POSE_STAMP_MALFORMED, A, FAULT,
         "a pose sample whose reference stamp does not decode: dropped"),
    _row(C.POSE_OTHER_REFERENCE, A, OK,
         "a pose stamped on another reference's clock than this agent's: used, its "
         "stamp ignored (placed by the sender's link estimate)"),
    _row(C.POSE_STALE_DROPPED, A, FAULT,
         "a followed pose too old on arrival to steer by (a burst queued through a link "
         "cut): never reaches the controller"),
    _row(C.POSE_OUT_OF_ORDER, (A, U), FAULT,
         "a pose older than the last taken from its source (a bridge: also a legacy "
         "agent's reply no newer than its last pose published): dropped"),
    _row(C.POSE_WITHHELD_NO_FIX, A, OK,
         "its own pose not published: no metrology fix yet (the filter's prior is no "
         "pose)"),
    _row(C.POSE_NOT_FINITE, A, FAULT,
         "its own pose not a finite number: never sent, and the platform held for good "
         "(nonfinite)"),
    _row(C.CONTESTED, (A, U), FAULT,
         "a peer found contested (two sessions speak for it): what it sent is dropped "
         "and its link's estimate reset"),
    _row(C.CONTESTED_DROPPED, (A, U), FAULT,
         "a pose or sync reply from a source that may not speak for its agent: dropped"),
    _row(C.SYNC_REQUESTS_SERVED, (A, U), OK,
         "a sync request answered (a bridge: on its legacy agent's behalf)"),
    _row(C.SYNC_REQUESTS_MALFORMED, (A, U), FAULT,
         "a sync request that does not decode: not answered"),
    _row(C.SYNC_REQUESTS_OVERSIZED, A, FAULT,
         "a sync request far larger than any: dropped unread, not answered"),
    _row(C.SYNC_REPLY_ERRORS, (A, U, R), FAULT,
         "a sync query answered with an error"),
    _row(C.SYNC_REPLIES_OVERSIZED, A, FAULT,
         "a sync reply far larger than any: dropped unread"),
    _row(C.SYNC_ATTACHMENT_MALFORMED, A, FAULT,
         "a sync reply's send-time attachment does not decode: the exchange taken with "
         "three timestamps"),
    _row(C.CLOCK_STEPS, A, FAULT,
         "a peer's clock (or its own) stepped, as a sync link's estimate saw it: that "
         "peer's poses count time afresh"),
    _row(C.REFERENCE_RESTARTED, A, FAULT,
         "a ctl run aborted here: the reference restarted (another session speaks for "
         "it)"),
    _row(C.REFERENCE_CLOCK_STEPS, A, FAULT,
         "a ctl run aborted here: the reference's clock stepped"),
    _row(C.ROUTER_LOST, A, FAULT,
         "a ctl run aborted here: the session lost its router"),
    _row(C.FIX_RESTART, A, FAULT,
         "a ctl run aborted here: the estimate restarted from agreeing outlier fixes"),
    _row(C.NAME_TAKEN_HOLDS, (A, U), FAULT,
         "another process runs under this agent's name: held for good (name_taken)"),
    _row(C.STALE_HOLDS, A, FAULT,
         "the followed pose went stale: held (stale)"),
    _row(C.CONTESTED_HOLDS, A, FAULT,
         "the followed agent became contested: held (contested)"),
    _row(C.NO_ROUTER_HOLDS, A, FAULT,
         "the session had no router for a second, after having one: held (no_router)"),
    _row(C.FIX_RESTART_HOLDS, A, FAULT,
         "the estimate restarted from agreeing outlier fixes: held until ctl reset "
         "(fix_restart)"),
    _row(C.HOLDS_RESTORED, A, FAULT,
         "a control step found the platform released while a hold stood: held again"),
    _row(C.SILENT_PEER_ALARMS, A, FAULT,
         "a peer alive (its liveliness token) began answering no sync request"),
    _row(C.CONTROL_RECEIVED, (A, U), OK,
         "a ctl command read (an abort counts however malformed)"),
    _row(C.CONTROL_MALFORMED, (A, U), FAULT,
         "a control sample that does not validate: dropped (an abort in it is still "
         "honoured)"),
    _row(C.COMMANDS_REPEATED, A, OK,
         "a command seen already (ctl publishes each one three times): dropped"),
    _row(C.COMMANDS_DROPPED, A, FAULT,
         "a command its gate refused (a stale or jumped sequence number): dropped, "
         "reported to ctl"),
    _row(C.COMMANDS_IGNORED, A, OK,
         "a command admitted but ignored (not for this agent, its run recorded here "
         "already, not in this mode): reported to ctl"),
    _row(C.LOOP_OVERRUNS, A, FAULT,
         "a control tick late by more than half a period: a step skipped"),
    _row(C.STATUS_WRITE_ERRORS, A, FAULT,
         "a status line not written to --status-json or to the run's recording (a full "
         "disk)"),
    # The run being recorded (its recorder's report, for this run only).
    _row(C.RECORDING_DROPPED_OVER_BUDGET, S.RECORDING, FAULT,
         "a message this run's recording left out: over its budget"),
    _row(C.RECORDING_DROPPED_QUEUE_FULL, S.RECORDING, FAULT,
         "a message this run's recording left out: its writer's queue was full"),
    _row(C.RECORDING_WRITE_ERRORS, S.RECORDING, FAULT,
         "a write to this run's recording that failed"),
    # The GNC chain (agents.gnc): a control step with every valve closed, per reason.
    _row(C.CLOSED_HELD, S.GNC, OK,
         "a control step closed: the platform held (safe hold)"),
    _row(C.CLOSED_NO_FIX, S.GNC, OK,
         "a control step closed: no metrology fix yet"),
    _row(C.CLOSED_DEVICE_RESTART, S.GNC, FAULT,
         "a control step closed: a serial device whose clock went back, not yet "
         "confirmed as restarted"),
    _row(C.CLOSED_FIX_RESTART, S.GNC, FAULT,
         "a control step closed: the estimate restarted from outlier fixes, not yet "
         "acknowledged (ctl reset)"),
    _row(C.CLOSED_FIX_REJECTED, S.GNC, FAULT,
         "a control step closed: the latest fix was rejected"),
    _row(C.CLOSED_STALE_FIX, S.GNC, FAULT,
         "a control step closed: the latest fix older than control.fix_timeout"),
    _row(C.CLOSED_STALE_IMU, S.GNC, FAULT,
         "a control step closed: no IMU sample for control.imu_timeout"),
    _row(C.CLOSED_SETTLING, S.GNC, OK,
         "a control step closed: the estimate's velocity not yet known"),
    _row(C.CLOSED_NONFINITE, S.GNC, FAULT,
         "a control step closed: a reference, the estimate or a demand not finite"),
    _row(C.IMU_REJECTED, S.GNC, FAULT,
         "an IMU sample not finite or beyond the sensor's range: dropped"),
    _row(C.FIX_REJECTED, S.GNC, FAULT,
         "a metrology fix rejected: not finite, outside, late or an outlier"),
    _row(C.FIX_OUTSIDE, S.GNC, FAULT,
         "a fix rejected: outside where a fix can be (the table and cameras' area)"),
    _row(C.FIX_OUTLIER, S.GNC, FAULT,
         "a fix rejected: further than navigation.fix_gate sigmas from the estimate"),
    _row(C.FIX_LATE, S.GNC, FAULT,
         "a fix rejected: older than vision.latency_max (a device time is wrong)"),
    _row(C.FIX_ACQUIRING, S.GNC, OK,
         "a fix held back until navigation.fixes_to_start in a row agree (after a start "
         "or a gap)"),
    _row(C.FIX_ACQUIRE_RESTARTS, S.GNC, FAULT,
         "a trial of fixes begun again: a fix disagreed with it, or a gap"),
    _row(C.FIX_UNCARRIED, S.GNC, OK,
         "a fix held back: older than the estimate's known motion (just restarted)"),
    _row(C.FIX_RESTARTS, S.GNC, FAULT,
         "the estimate restarted from agreeing outlier fixes"),
    _row(C.CLOCK_STEPS_BACK, S.GNC, FAULT,
         "time ran backwards: the estimate rebuilt from the next fix"),
    _row(C.RESTARTS, S.GNC, FAULT,
         "the estimate started afresh by its platform (a serial device restarted)"),
    # The serial platform (agents.serial.platform): the host's side.
    _row(C.FRAMES_SENT, (S.SERIAL, S.DEVICE), OK,
         "a frame written whole (the device: a frame it sent)"),
    _row(C.WRITE_TIMEOUTS, S.SERIAL, FAULT,
         "a write to the device timed out: valves not confirmed, all-closed sent"),
    _row(C.WRITE_SHORT, S.SERIAL, FAULT,
         "a write to the device stopped short: valves not confirmed, all-closed sent"),
    _row(C.DEVICE_FAILSAFE_REPORTS, S.SERIAL, FAULT,
         "a device STATUS saying its failsafe holds the valves closed"),
    _row(C.DEVICE_FRAMES_NOT_NEWER, S.SERIAL, FAULT,
         "a device frame no newer than the last of its kind (replayed or reordered): "
         "dropped"),
    _row(C.DEVICE_FRAMES_OFF_TIMELINE, S.SERIAL, FAULT,
         "a device frame off its timeline (an old frame, or a restart not yet "
         "confirmed): dropped"),
    _row(C.DEVICE_POSE_STALE, S.SERIAL, FAULT,
         "a device POSE older than the fix timeout against the IMU read with it: not a "
         "fix"),
    _row(C.DEVICE_RESTARTS, S.SERIAL, FAULT,
         "the device's clock began again, confirmed: the estimate restarted"),
    # Its frame decoder (agents.serial.protocol; the emulated device's are rx_*).
    _row(C.FRAMES_OK, S.SERIAL, OK,
         "a frame from the device decoded and accepted"),
    _row(C.BAD_CHECKSUM, S.SERIAL, FAULT,
         "a frame whose CRC does not match: dropped"),
    _row(C.GARBAGE_BYTES, S.SERIAL, FAULT,
         "a byte skipped outside any frame (before a sync pattern, or a rejected one)"),
    _row(C.OVERSIZE, S.SERIAL, FAULT,
         "a frame header claiming a payload over 64 bytes: rejected"),
    _row(C.UNKNOWN_TYPE, S.SERIAL, FAULT,
         "a good frame of a type not accepted: consumed, dropped"),
    _row(C.BAD_LENGTH, S.SERIAL, FAULT,
         "a good frame whose payload has the wrong length for its type: dropped"),
    _row(C.BAD_VALUE, S.SERIAL, FAULT,
         "a good frame carrying a float that is not finite: dropped"),
    _row(C.FRAME_BYTES, S.SERIAL, OK,
         "a byte of a frame with a good CRC (accepted or not)"),
    _row(C.BYTES_IN, S.SERIAL, OK,
         "a byte read from the device"),
    # Scenarios (agents.workspace, agents.relative, agents.docking, agents.formation).
    _row(C.WORKSPACE_CLAMPED, S.SCENARIO, OK,
         "a step whose track was clamped to the area, or slowed to what the platform "
         "can brake from"),
    _row(C.WORKSPACE_HOLDS, S.SCENARIO, FAULT,
         "the platform left its area: held for good (workspace)"),
    _row(C.RELATIVE_GIVEN, S.SCENARIO, OK,
         "a relative measurement given to the docking chaser"),
    _row(C.RELATIVE_OUT_OF_VIEW, S.SCENARIO, OK,
         "no relative measurement: the target out of the field of view or range"),
    _row(C.RELATIVE_DROPPED, S.SCENARIO, OK,
         "no relative measurement: an emulated dropout"),
    _row(C.RELATIVE_NO_POSE, S.SCENARIO, OK,
         "no relative measurement: nothing shared of the target yet"),
    _row(C.RELATIVE_STALE_POSE, S.SCENARIO, FAULT,
         "no relative measurement: the target's last pose older than the dead "
         "reckoning's horizon"),
    _row(C.BACKOFFS_CORRIDOR, S.SCENARIO, FAULT,
         "the chaser left the final approach's corridor: back to the approach"),
    _row(C.BACKOFFS_LOST, S.SCENARIO, FAULT,
         "the chaser's measurements stopped in the final approach: back to the approach"),
    _row(C.TARGET_JUMPS, S.SCENARIO, FAULT,
         "the target not where it was (beyond the jump gate): the approach begins again"),
    _row(C.MEMBERS_OFF_SLOT, S.SCENARIO, FAULT,
         "a formation member left out of a reference: too far from its slot"),
    _row(C.MEMBERS_TOO_FAST, S.SCENARIO, FAULT,
         "a formation member left out of a reference: too fast against the path"),
    # The UDP bridge (federation.bridge): its legacy agent's side, and the federation's.
    _row(C.UDP_REQUESTS_SENT, U, OK,
         "a sync request of the bridge's own sent to the legacy agent"),
    _row(C.UDP_FOREIGN, U, FAULT,
         "a datagram from a host other than --peer: dropped"),
    _row(C.UDP_HELD_FOR_NAME, U, FAULT,
         "a datagram dropped: the bridge no longer speaks for the legacy agent's name"),
    _row(C.UDP_REQUESTS_FOREIGN_PORT, U, FAULT,
         "a request from a port other than --request-port: dropped"),
    _row(C.UDP_REPLIES_FOREIGN_PORT, U, FAULT,
         "a reply from a port other than where replies may come from: dropped"),
    _row(C.UDP_MALFORMED, U, FAULT,
         "a datagram of neither size, or that does not decode: dropped"),
    _row(C.UDP_SELF, U, FAULT,
         "the bridge's own request came back (--peer is the bridge): dropped"),
    _row(C.UDP_REQUESTS_HELD, U, FAULT,
         "a legacy request not answered: aborted, until ctl reset"),
    _row(C.UDP_REQUESTS_UNSYNCED, U, OK,
         "a legacy request not answered: no reference time yet"),
    _row(C.UDP_REQUESTS_CONTESTED, U, FAULT,
         "a legacy request not answered: the followed agent is contested"),
    _row(C.UDP_REQUESTS_REFERENCE_GONE, U, FAULT,
         "a legacy request not answered: a follower bridge's reference left the "
         "federation"),
    _row(C.UDP_REQUESTS_NO_POSE, U, OK,
         "a legacy request not answered: no pose of the followed agent yet"),
    _row(C.UDP_REQUESTS_STALE, U, FAULT,
         "a legacy request not answered: the followed pose is stale"),
    _row(C.UDP_RATE_LIMITED, U, FAULT,
         "a legacy request over --request-rate-limit: not answered"),
    _row(C.UDP_REQUESTS_SERVED, U, OK,
         "a legacy request answered with the followed pose on reference time"),
    _row(C.UDP_SEND_ERRORS, U, FAULT,
         "a datagram the socket failed to send"),
    _row(C.UDP_RECEIVE_ERRORS, U, FAULT,
         "an error receiving on the socket (an ICMP error reported)"),
    _row(C.LEGACY_FOUND, U, OK,
         "the legacy agent answered, first or after it was lost"),
    _row(C.LEGACY_LOST, U, FAULT,
         "no accepted reply from the legacy agent for legacy_timeout: its estimate "
         "forgotten"),
    _row(C.LEGACY_RESTARTED, U, FAULT,
         "the legacy agent's clock stepped (it restarted): its pose forgotten"),
    _row(C.POSE_UNCONFIRMED, U, OK,
         "a legacy reply's pose not published: its time not yet confirmed by the "
         "estimate (warm-up)"),
    _row(C.POSE_PUBLISHED, U, OK,
         "a legacy agent's pose published on the federation"),
    _row(C.POSE_OTHER_AGENT, U, OK,
         "a pose of an agent the bridge does not follow (a former reference's): ignored"),
    _row(C.SYNC_REQUESTS_HELD, U, FAULT,
         "a sync request not answered: the bridge no longer speaks for the name"),
    _row(C.SYNC_REQUESTS_UNSYNCED, U, OK,
         "a sync request not answered: the legacy agent's clock not yet known"),
    _row(C.SYNC_REPLY_OVERSIZED, U, FAULT,
         "a reference's sync reply far larger than any: dropped unread"),
    _row(C.STATUS_NOT_ITS_OWN, U, FAULT,
         "a status line naming another agent than its key's: ignored"),
    _row(C.STATUS_MALFORMED, (U, R), FAULT,
         "a status line that does not validate (or, for ROS 2, names another agent or a "
         "clock offset no ROS time holds): ignored"),
    _row(C.STATUS_OVERSIZED, U, FAULT,
         "a status sample larger than any status line: dropped unread"),
    _row(C.CONTROL_OVERSIZED, U, FAULT,
         "a control sample larger than any status line: dropped unread"),
    # The ROS 2 bridge (federation.bridge.ros2): its forwarder, and a joined platform.
    _row(C.POSE_FOREIGN_KEY, R, FAULT,
         "a pose sample on a key not of an agent of this federation: dropped"),
    _row(C.ODOM_UNMAPPED, R, OK,
         "a pose not written to ROS: its agent's or the bridge's offset to the "
         "reference not yet known"),
    _row(C.ODOM_UNWRITABLE, R, FAULT,
         "a pose not written to ROS: no ROS time for its stamp, or its twist not finite"),
    _row(C.ODOM_PUBLISHED, R, OK,
         "an agent's pose written as nav_msgs/Odometry"),
    _row(C.TF_PUBLISHED, R, OK,
         "a /tf message written (the poses of one publish)"),
    _row(C.ODOM_RECEIVED, R, OK,
         "a joined platform's odometry sample taken as its pose"),
    _row(C.ODOM_CONTESTED, R, FAULT,
         "an odometry sample refused: more than one publisher on the topic"),
    _row(C.ODOM_FOREIGN_FRAME, R, FAULT,
         "an odometry sample refused: in other frames than the first taken"),
    _row(C.ODOM_CLOCK, R, FAULT,
         "an odometry sample refused: stamped over 2 s from this host's clock"),
    _row(C.ODOM_NOT_NEWER, R, FAULT,
         "an odometry sample refused: stamped no later than the last taken"),
    _row(C.ODOM_MALFORMED, R, FAULT,
         "an odometry sample refused: not finite, or not level"),
    _row(C.ODOM_STALE_HOLDS, R, FAULT,
         "no valid odometry for its timeout: held (source_stale)"),
    _row(C.POSE_WITHHELD, R, FAULT,
         "its own pose not published: the odometry is stale"),
    _row(C.ROS_HOLD_WRITTEN, R, OK,
         "the hold flag written on ROS 2 (a change, or its repeat every second)"),
    # The emulated serial device (agents.serial.emulator): the host's frames it read.
    _row(C.RX_FRAMES_OK, S.DEVICE, OK,
         "a frame from the host decoded and accepted"),
    _row(C.RX_BAD_CHECKSUM, S.DEVICE, FAULT,
         "a frame from the host whose CRC does not match: dropped"),
    _row(C.RX_GARBAGE_BYTES, S.DEVICE, FAULT,
         "a byte from the host skipped outside any frame"),
    _row(C.RX_OVERSIZE, S.DEVICE, FAULT,
         "a frame header from the host claiming a payload over 64 bytes: rejected"),
    _row(C.RX_UNKNOWN_TYPE, S.DEVICE, FAULT,
         "a good frame from the host of a type not accepted: dropped"),
    _row(C.RX_BAD_LENGTH, S.DEVICE, FAULT,
         "a good frame from the host with the wrong payload length: dropped"),
    _row(C.RX_BAD_VALUE, S.DEVICE, FAULT,
         "a good frame from the host carrying a float not finite: dropped"),
    _row(C.RX_FRAME_BYTES, S.DEVICE, OK,
         "a byte of a frame from the host with a good CRC"),
    _row(C.RX_BYTES_IN, S.DEVICE, OK,
         "a byte read from the host"),
    _row(C.FAILSAFE_TRIPS, S.DEVICE, FAULT,
         "no heartbeat within the device's timeout: its failsafe closed the valves"),
    _row(C.VALVES_IGNORED, S.DEVICE, FAULT,
         "a VALVES frame not applied: the failsafe holds"),
    _row(C.FIXES_UNSEEN, S.DEVICE, OK,
         "a POSE not sent: the platform outside the cameras' coverage"),
    _row(C.INJECTED_GARBAGE_BYTES, S.DEVICE, OK,
         "a garbage byte injected on the line (a fault asked for)"),
    _row(C.INJECTED_BAD_CRC, S.DEVICE, OK,
         "a frame sent with a bad CRC on purpose (a fault asked for)"),
)
# fmt: on
"""Every counter, in :class:`Count`'s order."""

BY_COUNT: dict[Count, CountRow] = {row.count: row for row in ROWS}


def counters_table_markdown() -> str:
    """The table of :data:`ROWS` as Markdown (``docs/counters.md``'s table)."""
    lines = ["| counter | counted by | fault | meaning |", "|---|---|---|---|"]
    for row in ROWS:
        by = ", ".join(source.value for source in row.by)
        fault = "yes" if row.fault else "no"
        lines.append(f"| `{row.count.value}` | {by} | {fault} | {row.meaning} |")
    return "\n".join(lines) + "\n"
