"""Issue 15, minor items: outputs are written atomically (PNGs too), the directory is fsynced after the
rename, results are readable by the operator's group (0640), and `pull` refuses an announced size it
was not promised."""

from __future__ import annotations

import asyncio
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from gprbot import atomic_files
from gprbot.errors import ProtocolError
from gprbot.gpr import render
from gprbot.gpr.bscan import BScan
from gprbot.shell.client import pull_run


def test_outputs_are_group_readable_and_the_directory_is_fsynced(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        synced.append(stat.S_IFMT(os.fstat(fd).st_mode))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    atomic_files.write_bytes_atomic(tmp_path / "pipes.json", b"{}\n")
    assert stat.S_IMODE((tmp_path / "pipes.json").stat().st_mode) == 0o640
    assert synced == [stat.S_IFREG, stat.S_IFDIR]  # the file, then the directory holding the new name


def test_pngs_are_written_atomically(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    renamed: list[tuple[str, str]] = []
    real_replace = os.replace

    def replace(src: str, dst: str) -> None:
        renamed.append((Path(src).name, Path(dst).name))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    rng = np.random.default_rng(0)
    bscan = BScan(data=rng.normal(size=(40, 64)).astype(np.float32), dt_ns=0.1, t0_ns=1.0,
                  positions=np.c_[np.linspace(0, 1, 40), np.zeros(40), np.zeros(40)], times=np.arange(40.0))
    render.write_bscan_png(tmp_path / "bscan.png", bscan)
    assert len(renamed) == 1 and renamed[0][1] == "bscan.png" and renamed[0][0].startswith(".bscan.png.")
    assert (tmp_path / "bscan.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


async def test_pull_refuses_an_announced_size_it_was_not_listed(tmp_path: Path) -> None:
    async def lying_server(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while line := await reader.readline():
            if line.startswith(b"files"):
                writer.write(b"= 10 small.bin\nok files 1\n")
            elif line.startswith(b"pull"):
                writer.write(b"ok pull 999999999999999 " + b"0" * 64 + b"\n" + b"x" * 65536)
            await writer.drain()
        writer.close()

    server = await asyncio.start_server(lying_server, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        with pytest.raises(ProtocolError, match="announced 999999999999999 bytes"):
            await pull_run("127.0.0.1", port, "run-1", tmp_path / "dest")
        assert not any((tmp_path / "dest").rglob("*.part"))
    finally:
        server.close()
        await server.wait_closed()
