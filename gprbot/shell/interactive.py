"""`gprbot shell HOST[:PORT]` (interactive, with readline history) and `gprbot pull HOST[:PORT] RUN [DIR]`."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import shlex
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType

from gprbot.config import DEFAULT_SHELL_PORT
from gprbot.errors import GprbotError
from gprbot.shell.auth import load_token
from gprbot.shell.client import ShellCommandError, ShellConnection, parse_address, pull_run, safe_relative
from gprbot.shell.protocol import ServerReply

HISTORY_FILE = Path.home() / ".gprbot_history"
PROMPT = "gprbot> "

readline: ModuleType | None
try:
    import readline
except ImportError:  # Windows laptops: no history, otherwise the same
    readline = None


def add_shell_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of `gprbot shell`."""
    parser.add_argument("address", metavar="HOST[:PORT]", help=f"the robot (port {DEFAULT_SHELL_PORT} by default)")
    parser.add_argument("--token-file", type=Path, help="file holding the shell token (mode 0600)")
    parser.add_argument("-c", "--command", action="append", metavar="CMD",
                        help="run CMD (repeatable, in order) and exit: 0 if every reply is ok, 1 at the first error")


def add_pull_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of `gprbot pull`."""
    parser.add_argument("address", metavar="HOST[:PORT]", help=f"the robot (port {DEFAULT_SHELL_PORT} by default)")
    parser.add_argument("run", help="run name (see `runs` in the shell)")
    parser.add_argument("dir", nargs="?", type=Path, help="where to write the files (default: ./RUN)")
    parser.add_argument("--token-file", type=Path, help="file holding the shell token (mode 0600)")


def run_shell(args: argparse.Namespace) -> int:
    """Run the interactive shell until `quit`, end of input or the robot hanging up."""
    host, port = parse_address(args.address)
    token = load_token(args.token_file) if args.token_file else None
    if getattr(args, "command", None):
        return asyncio.run(_scripted(host, port, token, args.command))
    return asyncio.run(_interactive(host, port, token))


def run_pull(args: argparse.Namespace) -> int:
    """Pull one run's files; prints each file written."""
    host, port = parse_address(args.address)
    token = load_token(args.token_file) if args.token_file else None
    dest = args.dir if args.dir is not None else Path(args.run)
    for path in asyncio.run(pull_run(host, port, args.run, dest, token)):
        print(path)
    return 0


def shell_main(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry point of `gprbot shell` (parses `argv`)."""
    parser = argparse.ArgumentParser(prog="gprbot shell", description="talk to a robot's command shell")
    add_shell_arguments(parser)
    return _guarded(run_shell, parser.parse_args(argv))


def pull_main(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry point of `gprbot pull` (parses `argv`)."""
    parser = argparse.ArgumentParser(prog="gprbot pull", description="download a run's results, sha256-checked")
    add_pull_arguments(parser)
    return _guarded(run_pull, parser.parse_args(argv))


def _guarded(run: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    try:
        return int(run(args))
    except GprbotError as exc:
        print(f"gprbot: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


def print_event(text: str) -> None:
    """Print an event above the line being typed, then redraw the prompt and what was typed so far."""
    if not sys.stdout.isatty():
        print(f"* {text}", flush=True)
        return
    typed = readline.get_line_buffer() if readline is not None else ""
    sys.stdout.write(f"\r\x1b[K* {text}\n{PROMPT}{typed}")
    sys.stdout.flush()


def print_reply(reply: ServerReply) -> None:
    """Print a reply as the server sent it."""
    for line in reply.body:
        print(f"  {line}")
    print(f"ok {reply.text}".rstrip() if reply.ok else f"error {reply.code} {reply.text}")


async def _scripted(host: str, port: int, token: str | None, commands: Sequence[str]) -> int:
    """`gprbot shell -c CMD ...`: each command's reply printed; exit 1 at the first error reply, else 0."""
    async with ShellConnection(host, port, on_event=print_event) as conn:
        if token is not None:
            await conn.authenticate(token)
        for line in commands:
            if not await _run_line(conn, line):
                return 1
    return 0


async def _run_line(conn: ShellConnection, line: str) -> bool:
    """Send one command line (a `pull` fetches here) and print its reply; whether it succeeded."""
    try:
        if line.split()[:1] == ["pull"]:
            await _pull_here(conn, line)
            return True
        reply = await conn.request(line)
    except ShellCommandError as exc:
        reply = exc.reply
    print_reply(reply)
    return reply.ok


async def _interactive(host: str, port: int, token: str | None) -> int:
    """The prompt; like sh, the exit status is that of the last command (1 if its reply was an error)."""
    status = 0
    async with ShellConnection(host, port, on_event=print_event) as conn:
        if token is not None:
            await conn.authenticate(token)
        print(f"connected to {host}:{port}; `help` for commands, `quit` to leave")
        ready = threading.Event()
        lines = _start_input_thread(asyncio.get_running_loop(), ready)
        while True:
            ready.set()
            line = await lines.get()
            if line is None:
                break
            words = line.split()
            if not words:
                continue
            if words[0] in ("quit", "exit"):
                break
            status = 0 if await _run_line(conn, line) else 1
    _save_history()
    return status


async def _pull_here(conn: ShellConnection, line: str) -> None:
    """`pull RUN FILE` typed at the prompt: save the file in the current directory, not on the terminal."""
    words = shlex.split(line)
    if len(words) != 3:
        print("usage: pull RUN FILE (saved in the current directory)")
        return
    target = Path.cwd() / safe_relative(words[2]).name
    path = await conn.pull_file(words[1], words[2], target)
    print(f"ok saved {path} ({path.stat().st_size} bytes, sha256 verified)")


def _start_input_thread(loop: asyncio.AbstractEventLoop, ready: threading.Event) -> asyncio.Queue[str | None]:
    """Read lines in a daemon thread (so a hang-up can end the program while input() blocks).

    The thread prompts again only once `ready` is set, i.e. after the previous reply was printed.
    """
    queue: asyncio.Queue[str | None] = asyncio.Queue()
    if readline is not None:
        with contextlib.suppress(OSError):
            readline.read_history_file(HISTORY_FILE)

    def read_lines() -> None:
        while True:
            ready.wait()
            ready.clear()
            try:
                line: str | None = input(PROMPT)
            except (EOFError, KeyboardInterrupt):
                line = None
            loop.call_soon_threadsafe(queue.put_nowait, line)
            if line is None:
                return

    threading.Thread(target=read_lines, name="gprbot-shell-input", daemon=True).start()
    return queue


def _save_history() -> None:
    if readline is not None:
        with contextlib.suppress(OSError):
            readline.write_history_file(HISTORY_FILE)
