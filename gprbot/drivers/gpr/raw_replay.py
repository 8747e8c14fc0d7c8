"""The GPR's raw stream from a run log, through the same parser and clock as on the robot (sans-IO).

The driver records a GprStreamSetup as each data-socket connection's parser starts and a GprRawChunk per
read; `traces_from_raw` feeds them to a TraceStreamParser per connection, one TraceCounter (numbering
across NIC restarts) and one NicClock (receive times → host times), so the parser's resync, gap and
duplicate decisions replay byte for byte. What the live queue dropped when full is not in the log's
Trace records either way; here such traces come back.
"""

from __future__ import annotations

from collections.abc import Iterable

from gprbot.drivers.gpr.sdk_client import NicClock
from gprbot.drivers.gpr.trace_stream import TraceCounter, TraceFrame, TraceStreamParser
from gprbot.errors import ProtocolError
from gprbot.messages import GprRawChunk, GprStreamSetup, Trace


def trace_of(frame: TraceFrame, clock: NicClock, received_s: float, dt_ns: float, t0_ns: float) -> Trace:
    """The Trace message of a parsed frame received at host time received_s (the driver's step, and replay's)."""
    return Trace(t=clock.to_host(frame.device_time_s, received_s), number=frame.sequence, samples=frame.samples,
                 dt_ns=dt_ns, t0_ns=t0_ns, stacks=frame.stacks)


def traces_from_raw(records: Iterable[GprStreamSetup | GprRawChunk]) -> list[Trace]:
    """The traces the driver delivered, re-parsed from its recorded raw stream (in log order)."""
    counter, clock = TraceCounter(), NicClock()
    parser: TraceStreamParser | None = None
    setup: GprStreamSetup | None = None
    traces: list[Trace] = []
    for record in records:
        if isinstance(record, GprStreamSetup):
            if record.new_epoch:
                counter.new_epoch()
            parser, setup = TraceStreamParser(record.points_per_trace, record.stacks, counter), record
            continue
        if parser is None or setup is None or record.session != setup.session:
            raise ProtocolError(f"raw GPR bytes of connection {record.session} without its setup record; "
                                "the run log is cut before them — replay its Trace records instead")
        for event in parser.feed(record.data):
            if isinstance(event, TraceFrame):
                traces.append(trace_of(event, clock, record.t, setup.dt_ns, setup.t0_ns))
    return traces
