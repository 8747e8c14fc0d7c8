"""The console's run endpoints: the list of runs, one run's results document, its files for download.

Names are validated by the shell's own `pull` grammar and files opened by the shell's run-file code,
so the console serves exactly what `gprbot pull` would (nothing outside the runs directory).
"""

from __future__ import annotations

import asyncio
import shlex
from collections.abc import Callable
from pathlib import Path

from aiohttp import web

from gprbot.outputs.run_document import run_document
from gprbot.shell import runfiles
from gprbot.shell.commands import CommandError, Pull, parse_command


def checked_pull(run: str, name: str) -> Pull:
    """The shell's validation of a run and file name (no '..', no absolute paths); 400 if refused."""
    try:
        command = parse_command(f"pull {shlex.quote(run)} {shlex.quote(name)}")
    except CommandError as exc:
        raise web.HTTPBadRequest(text=exc.text, content_type="text/plain") from None
    assert isinstance(command, Pull)
    return command


class RunRoutes:
    """GET /api/runs, /api/runs/{run}, /runs/{run}/{file}; `authorise(request)` raises 401 without a session."""

    def __init__(self, runs_dir: Path, authorise: Callable[[web.Request], object]) -> None:
        self.runs_dir, self._authorise = runs_dir, authorise

    def routes(self) -> list[web.RouteDef]:
        """The route table entries."""
        return [web.get("/api/runs", self.runs), web.get("/api/runs/{run}", self.run),
                web.get("/runs/{run}/{name:.+}", self.run_file)]

    async def runs(self, request: web.Request) -> web.StreamResponse:
        """The run directories, newest first."""
        self._authorise(request)
        return web.json_response({"runs": await asyncio.to_thread(runfiles.list_runs, self.runs_dir)})

    async def run(self, request: web.Request) -> web.StreamResponse:
        """One run's results document (pipes, clouds, pictures, files)."""
        self._authorise(request)
        run = checked_pull(request.match_info["run"], "summary.json").run
        try:
            document = await asyncio.to_thread(run_document, self.runs_dir, run)
        except CommandError as exc:
            raise web.HTTPNotFound(text=exc.text, content_type="text/plain") from None
        return web.json_response(document)

    async def run_file(self, request: web.Request) -> web.StreamResponse:
        """A run's file (`?download=1`: as an attachment), with its sha256 in X-Content-SHA256."""
        self._authorise(request)
        pull = checked_pull(request.match_info["run"], request.match_info["name"])
        try:
            opened = await asyncio.to_thread(runfiles.open_run_file, self.runs_dir, pull.run, pull.file)
        except CommandError as exc:
            raise web.HTTPNotFound(text=exc.text, content_type="text/plain") from None
        opened.handle.close()
        response = web.FileResponse(opened.path)
        if request.query.get("download"):
            response.headers["Content-Disposition"] = f'attachment; filename="{opened.path.name}"'
        response.headers["X-Content-SHA256"] = opened.sha256
        return response
