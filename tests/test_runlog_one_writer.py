"""Issue 15 #6: one run-log writer ever, even when a write stalls past the recorder's watchdog; short frames."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest

from gprbot.messages import SurveyEvent
from gprbot.robot.recorder import Recorder
from gprbot.runlog import KIND_MESSAGE, RunLogWriter, frame
from gprbot.runlog_reader import RunLogReader


class _StallingWrites:
    """Wraps RunLogWriter.append: the first write blocks until released; counts concurrent writers."""

    def __init__(self, writer: RunLogWriter) -> None:
        self._append = writer.append
        self.gate = threading.Event()
        self.stalled = threading.Event()
        self.active = 0
        self.max_active = 0
        self.calls = 0
        self._lock = threading.Lock()

    def __call__(self, message: object, t: float) -> None:
        with self._lock:
            self.active += 1
            self.max_active = max(self.max_active, self.active)
            self.calls += 1
            first = self.calls == 1
        if first:
            self.stalled.set()
            self.gate.wait(10.0)
        try:
            self._append(message, t)
        finally:
            with self._lock:
                self.active -= 1


async def test_a_stalled_write_cancelled_by_the_watchdog_never_gets_a_second_writer(tmp_path: Path) -> None:
    recorder = Recorder(flush_s=0.005)
    recorder.open(tmp_path, {"run": "stall"})
    assert recorder.writer is not None
    stalling = _StallingWrites(recorder.writer)
    recorder.writer.append = stalling  # type: ignore[method-assign]
    first = asyncio.create_task(recorder.run(lambda: None))
    for i in range(5):
        recorder.append(SurveyEvent(float(i), "line_start", i), float(i))
    await asyncio.to_thread(stalling.stalled.wait, 5.0)
    first.cancel()  # what the supervisor does when the watchdog deadline passes
    with pytest.raises(asyncio.CancelledError):
        await first
    second = asyncio.create_task(recorder.run(lambda: None))  # the restarted task
    for i in range(5, 10):
        recorder.append(SurveyEvent(float(i), "line_start", i), float(i))
    await asyncio.sleep(0.1)  # the restarted task flushes while the first write still hangs
    closing = asyncio.create_task(recorder.close({"state": "done"}))
    await asyncio.sleep(0.05)
    stalling.gate.set()
    await closing
    second.cancel()
    with pytest.raises(asyncio.CancelledError):
        await second
    assert stalling.max_active == 1
    reader = RunLogReader(tmp_path)
    lines = [record.message.line for record in reader]
    assert lines == list(range(10))
    assert reader.ended and reader.skipped == 0
    assert recorder.records == 10


async def test_the_recorder_keeps_beating_while_the_disk_stalls(tmp_path: Path) -> None:
    recorder = Recorder(flush_s=0.005, stall_report_s=0.05)
    recorder.open(tmp_path, {"run": "slow disk"})
    assert recorder.writer is not None
    stalling = _StallingWrites(recorder.writer)
    recorder.writer.append = stalling  # type: ignore[method-assign]
    beats = 0

    def beat() -> None:
        nonlocal beats
        beats += 1

    task = asyncio.create_task(recorder.run(beat))
    recorder.append(SurveyEvent(0.0, "line_start", 0), 0.0)
    await asyncio.to_thread(stalling.stalled.wait, 5.0)
    before = beats
    await asyncio.sleep(0.3)
    assert beats > before  # alive: the task waits for the disk without missing its watchdog
    assert recorder.last_error is not None and "stalled" in recorder.last_error
    stalling.gate.set()
    await recorder.close({})
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


@pytest.mark.parametrize("payload", [KIND_MESSAGE, KIND_MESSAGE + b"\x00" * 7, KIND_MESSAGE + b"\x00" * 8])
def test_a_valid_checksum_frame_shorter_than_a_message_is_skipped_not_a_crash(tmp_path: Path, payload: bytes) -> None:
    writer = RunLogWriter(tmp_path, {"run": "short"})
    writer.append(SurveyEvent(1.0, "line_start", 0), 1.0)
    writer.close({"state": "done"})
    path = tmp_path / "log-000.msgpack"
    data = path.read_bytes()
    first_end = data.index(b"GRL1", 4)  # after the header frame
    second = data.index(b"GRL1", first_end + 4)  # the end marker
    path.write_bytes(data[:second] + frame(payload) + data[second:])
    reader = RunLogReader(tmp_path)
    records = list(reader)
    assert [r.message.line for r in records] == [0]
    assert reader.skipped == 1 and "skipped" in reader.note
    assert reader.ended
