"""Score MigrationNet checkpoints (or ONNX models) on the FDTD dev half and the real files, for model selection.

    python -m training.select_fdtd training/checkpoints/migrationnet_dr_e*.pt models/migrationnet.onnx

Each checkpoint is exported to ONNX next to it (…/onnx/NAME.onnx with its card) and run through
`validation.evaluate`'s cases and scoring with the velocity given (FDTD dev) and estimated by the chain
(real files). Never the FDTD test half: that is reported once, not selected on.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from validation.cases import Case, fdtd_cases, real_cases
from validation.evaluate import Row, run_case, summary
from validation.methods import methods_with_migrationnet
from validation.scoring import match

EXPORT_SCRIPT = Path(__file__).resolve().parent.parent / "tools" / "export_onnx.py"

GROUPS = ("fdtd-dev", "real")
_KEYS = ("pipes ≤3 cm", "pipes ≤1 cm", "radius ≤30 %", "false pipes / scene", "median s / B-scan")


def onnx_of(model: Path) -> Path:
    """The ONNX file to score: the model itself, or a checkpoint exported next to it."""
    if model.suffix == ".onnx":
        return model.resolve()
    out = model.parent / "onnx" / f"{model.stem}.onnx"
    if not out.exists() or out.stat().st_mtime < model.stat().st_mtime:
        _export_tool().export("migrationnet", model, out)
    return out.resolve()


def _export_tool() -> ModuleType:
    """tools/export_onnx.py (a script, not a package)."""
    spec = importlib.util.spec_from_file_location("export_onnx", EXPORT_SCRIPT)
    if spec is None or spec.loader is None:
        raise RuntimeError(f"cannot load {EXPORT_SCRIPT}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def cases() -> list[Case]:
    """The FDTD dev half and the real files."""
    return [c for c in fdtd_cases() + real_cases() if c.group in GROUPS]


def score_model(model: Path) -> dict[str, dict[str, str]]:
    """Summary figures per (group, mode) of one model."""
    methods = methods_with_migrationnet(onnx_of(model))
    rows: list[Row] = []
    for case in cases():
        mode = "given" if case.velocity is not None and case.group != "real" else "estimated"
        rows.append(run_case(case, "migrationnet", mode, methods))
    out = {}
    for group in GROUPS:
        picked = [r for r in rows if r.case.group == group]
        if picked:
            out[f"{group} ({picked[0].mode})"] = summary(picked)
    real = [r for r in rows if r.case.group == "real"]
    hits = [len(match(r.outcome.found, r.case.targets, r.case.tolerance_m)) for r in real]
    total = sum(len(r.case.targets) for r in real)
    extra = sum(len(r.outcome.found) - h for r, h in zip(real, hits, strict=True))
    per_file = ", ".join(f"{r.case.name.split(' (')[0]} {h}/{len(r.case.targets)}+{len(r.outcome.found) - h}"
                         for r, h in zip(real, hits, strict=True))
    out["real files"] = {"found": f"{sum(hits)}/{total} targets, {extra} detections on no target ({per_file})"}
    return out


def main(argv: list[str] | None = None) -> int:
    """Score each model and print one line per model and set."""
    parser = argparse.ArgumentParser(prog="python -m training.select_fdtd", description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", type=Path, help="checkpoints (.pt) or ONNX models")
    args = parser.parse_args(argv)
    for model in args.models:
        for what, figures in score_model(model).items():
            print(f"{model.name} | {what} | " + " | ".join(f"{k} {figures[k]}" for k in _KEYS if k in figures)
                  + figures.get("found", ""), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
