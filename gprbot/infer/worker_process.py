"""The inference worker's child side: its main loop and the jobs it runs, and the results it sends back.

This module imports no numpy at the top, so that the child sets its thread counts before numpy/BLAS load.
"""

from __future__ import annotations

import os
import signal
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from gprbot import errors
from gprbot.config import Config

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

    from gprbot.gpr.bscan import BScan
    from gprbot.gpr.interpret import CrossSection
    from gprbot.reconstruct.register import SliceCloud
    from gprbot.reconstruct.survey_result import SurveyResult

_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


@dataclass(frozen=True)
class BScanSummary:
    """What preprocessing made of a line: its size, sample interval, length and the steps applied."""

    n_traces: int
    n_samples: int
    dt_ns: float
    length_m: float
    processing: tuple[str, ...]


@dataclass(frozen=True)
class LineJobResult:
    """The preview interpretation of one line, with the velocity used and per-stage timings (s)."""

    line: int
    bscan: BScanSummary
    section: CrossSection
    slice: SliceCloud
    velocity_m_per_ns: float
    velocity_source: str  # "hint" | "config" | "line estimate" | "default guess"
    timings_s: dict[str, float] = field(default_factory=dict)



def serve(conn: Connection, cfg: Config, threads: int) -> None:
    """The worker process's main loop: set thread counts, warm up, then answer jobs until stop or EOF."""
    for name in _THREAD_VARIABLES:
        os.environ[name] = str(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the daemon's to handle; it stops us
    began = time.perf_counter()
    jobs = _load_jobs()
    conn.send(("ready", {"warmup_s": time.perf_counter() - began, "pid": os.getpid()}))
    while True:
        try:
            kind, args = conn.recv()
        except EOFError:
            return  # the daemon is gone
        if kind == "stop":
            return
        conn.send(("started",))
        began = time.perf_counter()
        try:
            result = jobs[kind](cfg, *args)
        except Exception as exc:  # every failure goes back to the caller, the worker lives on
            conn.send(("failed", type(exc).__name__, str(exc), traceback.format_exc()))
            continue
        conn.send(("done", result, time.perf_counter() - began))


def _load_jobs() -> dict[str, Callable[..., Any]]:
    """Import the pipeline (the warm-up: numpy, scipy and the interpreters load here, not in the first job)."""
    import gprbot.infer.pipeline  # noqa: F401

    return {"interpret_line": _interpret_line_job, "finish_survey": _finish_survey_job,
            "write_outputs": _write_outputs_job}


def _interpret_line_job(cfg: Config, line: int, bscan: BScan, velocity_hint: float | None) -> LineJobResult:
    from gprbot.gpr.preprocess import preprocess
    from gprbot.infer.pipeline import interpret_line

    began = time.perf_counter()
    processed = preprocess(bscan, cfg.gpr)
    preprocessed = time.perf_counter()
    velocity, source, hints = _line_velocity(processed, cfg, velocity_hint)
    estimated = time.perf_counter()
    result = interpret_line(line, processed, cfg, velocity, hints)
    done = time.perf_counter()
    along = processed.along_track_m()
    summary = BScanSummary(int(processed.data.shape[0]), int(processed.data.shape[1]), processed.dt_ns,
                           float(along.max() - along.min()), processed.processing)
    timings = {"preprocess": preprocessed - began, "velocity": estimated - preprocessed, "interpret": done - estimated}
    return LineJobResult(line, summary, result.section, result.slice, velocity, source, timings)


def _line_velocity(processed: BScan, cfg: Config, hint: float | None) -> tuple[float, str, tuple[Any, ...]]:
    """The velocity for a preview of one line: the caller's hint, the configured eps_r, or this line's fit."""
    from gprbot.gpr.traveltime import velocity_from_eps
    from gprbot.gpr.velocity import V_GUESS_M_PER_NS
    from gprbot.infer.pipeline import survey_velocity

    if hint is not None:
        return hint, "hint", ()
    if cfg.gpr.eps_r is not None:
        return velocity_from_eps(cfg.gpr.eps_r), "config", ()
    try:
        found = survey_velocity({0: processed}, cfg)
        velocity, hints = found.v, found.hints
    except errors.InterpretationError:
        return V_GUESS_M_PER_NS, "default guess", ()  # no hyperbola on this line: finish_survey fits all lines
    return velocity, "line estimate", hints


def _finish_survey_job(cfg: Config, bscans: dict[int, BScan]) -> SurveyResult:
    import numpy as np

    from gprbot.infer.pipeline import reconstruct_survey

    return reconstruct_survey(bscans, cfg, np.random.default_rng(cfg.reconstruction_seed))


def _write_outputs_job(cfg: Config, out_dir: str, result: SurveyResult, meta: dict[str, Any],
                       extent: tuple[float, float, float, float], truth_axes: list[Any],
                       raw_lines: dict[int, BScan]) -> list[str]:
    # Here, not in the daemon: matplotlib holds the GIL for seconds per picture, and the daemon's
    # event loop runs the 50 Hz motor control.
    from pathlib import Path

    from gprbot.outputs.run_dir import write_survey_outputs

    return [str(p) for p in write_survey_outputs(Path(out_dir), result, meta, extent, truth_axes,
                                                 raw_lines=raw_lines)]
