"""report.html: the console's results page for one run as one self-contained file (opens offline).

The page's scripts, its style, three.js, the run's data (pipes, clouds) and its pictures are all
inlined, so a run directory pulled to a laptop opens by double-click with no network and no server.
Downloads link to the files beside it in the run directory.
"""

from __future__ import annotations

import base64
import json
import logging
import re
from pathlib import Path
from typing import Any

from gprbot.atomic_files import write_bytes_atomic
from gprbot.outputs.run_document import run_document

log = logging.getLogger(__name__)
STATIC_DIR = Path(__file__).parents[1] / "web" / "static"  # the console's own page, inlined
THREE_JS = STATIC_DIR / "vendor" / "three-0.170.0.module.min.js"
REPORT_NAME = "report.html"
PAGE_SCRIPTS = ("draw.js", "viewer.js", "results.js")


def _script_safe(text: str, name: str) -> str:
    """Our own script, checked that it cannot end the <script> element it is inlined in."""
    if "</script" in text.lower() or "<!--" in text:
        raise ValueError(f"{name} holds '</script' or '<!--' and cannot be inlined in report.html")
    return text


def _data_url(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()


def report_html(run_dir: Path) -> str:
    """The report page of the run in `run_dir` (CommandError if it is not a run directory)."""
    document: dict[str, Any] = run_document(run_dir.parent, run_dir.name)
    pictures = [document["map"]] if document["map"] else []
    pictures += [name for line in document["lines"] for key, name in line.items() if key != "line"]
    document["inline_pictures"] = {name: _data_url(run_dir / name) for name in pictures}
    three = THREE_JS.read_text(encoding="utf-8")
    if "</script" in three.lower() or "<!--" in three:  # a future three.js: carry it base64 instead
        three_block = f'<script id="three-b64" type="text/plain">{base64.b64encode(three.encode()).decode()}</script>'
    else:
        three_block = f'<script id="three-src" type="text/plain">{three}</script>'
    scripts = "\n".join(f"<script>{_script_safe((STATIC_DIR / name).read_text(encoding='utf-8'), name)}</script>"
                        for name in PAGE_SCRIPTS)
    template = (STATIC_DIR / "report_template.html").read_text(encoding="utf-8")
    values = {
        "title": f"gprbot run {run_dir.name}",
        "style": (STATIC_DIR / "console.css").read_text(encoding="utf-8"),
        "data": json.dumps(document, allow_nan=False).replace("<", "\\u003c"),  # no '</script>' inside
        "three": three_block,
        "scripts": scripts,
    }
    return re.sub(r"\{\{(\w+)\}\}", lambda m: values[m.group(1)], template)  # one pass: data may hold braces


def write_report(run_dir: Path) -> Path:
    """Write run_dir/report.html atomically; its path."""
    path = run_dir / REPORT_NAME
    write_bytes_atomic(path, report_html(run_dir).encode("utf-8"))
    return path


def write_report_safely(run_dir: Path) -> Path | None:
    """write_report for the daemon: a failure is logged (the run's other files are already written)."""
    try:
        return write_report(run_dir)
    except Exception:
        log.exception("report.html for %s could not be written", run_dir)
        return None
