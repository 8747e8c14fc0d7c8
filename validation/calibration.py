"""Our forward model against the gprMax FDTD scenes: B-scan correlation, apex times, amplitudes, flanks, wavelets.

`python -m validation.calibration [--only NAME] [--half dev] [--out docs/eval/sim_vs_fdtd.md] [--png DIR]`
renders each FDTD scene with `gprbot.sim` (see `validation.calib_scene`) and writes the residual as a
markdown report. The text between the report's findings markers is kept when the report is rewritten.
`--phase/--peak-factor/--footprint` render one point of the training data's domain randomisation
(`gprbot.sim.variation`) instead of the default simulator, to check that its ranges cover the FDTD.
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.sim.variation import SignalVariation
from validation import calib_measure as m
from validation.calib_scene import below_of, debye_of, load_fdtd, picture, render_ours, scene_names, stones_of

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "docs" / "eval" / "sim_vs_fdtd.md"
FINDINGS = ("<!-- findings -->", "<!-- /findings -->")


@dataclass
class ReflectorRow:
    """One truth target compared: apex times (ns), amplitude ratios ours/FDTD, flank moveout differences (ns)."""

    scene: str
    what: str
    radius_m: float
    depth_m: float
    t_fdtd: float = math.nan
    t_ours: float = math.nan
    amp_vs_direct: float = math.nan  # (A / A_direct)_ours / (A / A_direct)_fdtd
    amp_vs_first: float = math.nan  # (A / A_first)_ours / (A / A_first)_fdtd
    amp_vs_first_3d: float = math.nan  # amp_vs_first with the FDTD's 2D spreading turned 3D: × sqrt(t_first / t)
    moveout: dict[float, float] = field(default_factory=dict)  # angle → Δ(t_flank − t_apex), ours − FDTD
    flank_amp: dict[float, float] = field(default_factory=dict)  # angle → (A_flank/A_apex)_ours / (..)_fdtd
    flank_amp_3d: dict[float, float] = field(default_factory=dict)  # the same, FDTD spreading turned 3D
    multiple: tuple[float, float] = (math.nan, math.nan)  # surface multiple / primary at the apex: ours, FDTD

    @property
    def dt_apex(self) -> float:
        """Apex time, ours minus FDTD (ns)."""
        return self.t_ours - self.t_fdtd


@dataclass
class SceneResult:
    """Whole-B-scan figures of one scene and its reflector rows."""

    name: str
    half: str
    frequency_mhz: float
    notes: str
    ncc: float
    ncc_env: float
    shift_ns: float
    ncc_shifted: float
    polarity: float  # −1: the FDTD records the opposite sign (ours flipped before every correlation)
    direct_corr: float
    direct_lag_ns: float
    f_direct: tuple[float, float]  # dominant frequency (MHz) of the direct wave: FDTD, ours
    f_apex: tuple[float, float]  # of the first reflector's apex wavelet: FDTD, ours
    apex_corr: float  # signed correlation of the first reflector's apex wavelets at their best lag
    rows: list[ReflectorRow]


def compare(name: str, variation: SignalVariation | None = None) -> SceneResult:
    """Render scene `name` with our simulator (or one variation of it) and measure it against the FDTD B-scan."""
    fdtd_raw, truth = load_fdtd(name)
    debye = debye_of(name)
    ours_raw = render_ours(truth, fdtd_raw.shape[1], debye, variation=variation)
    dt, f = float(truth["dt_ns"]), float(truth["frequency_mhz"])
    period = 1e3 / f
    end = int(m.direct_window_ns(truth) / dt)
    med_f, med_o = np.median(fdtd_raw, axis=0)[:end], np.median(ours_raw, axis=0)[:end]
    d_corr, d_lag = m.wavelet_corr(med_f, med_o, round(period / dt))
    polarity = 1.0 if d_corr >= 0 else -1.0  # the recording's sign is a convention: match the direct waves
    a, b = m.preprocess(fdtd_raw), polarity * m.preprocess(ours_raw)
    lag, shifted = m.best_shift(b, a, round(1.5 * period / dt))
    ncc_env = m.ncc(m.envelope(b) - m.envelope(b).mean(), m.envelope(a) - m.envelope(a).mean())
    amp_dir_f, amp_dir_o = float(np.max(np.abs(med_f))), float(np.max(np.abs(med_o)))
    env_f, env_o = m.envelope(fdtd_raw - fdtd_raw.mean(0)), m.envelope(ours_raw - ours_raw.mean(0))
    xs = np.asarray(truth["trace_x_m"])
    rows: list[ReflectorRow] = []
    first: tuple[float, float, float] | None = None
    f_apex, apex_corr = (math.nan, math.nan), math.nan
    for r in m.reflectors(truth):
        row = ReflectorRow(name, f"{r.kind} {r.fill}", r.radius_m, r.depth_m)
        i = int(np.argmin(np.abs(xs - r.x_m)))
        t0 = m.predicted_ns(truth, xs[i], r)
        travel = t0 - float(truth["source_peak_ns"])
        row.t_fdtd, af = m.pick(env_f[i], t0, 0.5 * period, dt)
        row.t_ours, ao = m.pick(env_o[i], t0, 0.5 * period, dt)
        row.amp_vs_direct = (ao / amp_dir_o) / (af / amp_dir_f)
        if r.fill == "metal" and r.kind == "pipe":  # pipe → surface → pipe: one more two-way trip over the cover
            t_mult = t0 + 2.0 * (r.depth_m - r.radius_m) / float(truth["velocity_m_per_ns"])
            if t_mult < (fdtd_raw.shape[1] - 1) * dt:
                mo, mf = m.pick(env_o[i], t_mult, 0.5 * period, dt)[1], m.pick(env_f[i], t_mult, 0.5 * period, dt)[1]
                row.multiple = (mo / ao, mf / af)
        if first is None:
            first = (af, ao, travel)
            wf = m.window(fdtd_raw[i] - fdtd_raw.mean(0)[i], row.t_fdtd, period, dt)
            wo = m.window(ours_raw[i] - ours_raw.mean(0)[i], row.t_ours, period, dt)
            f_apex = (m.dominant_mhz(wf, dt), m.dominant_mhz(wo, dt))
            apex_corr = polarity * m.wavelet_corr(wf, wo, round(0.5 * period / dt))[0]
        else:
            row.amp_vs_first = (ao / first[1]) / (af / first[0])
            row.amp_vs_first_3d = row.amp_vs_first / math.sqrt(first[2] / travel)
        for angle in m.ANGLES_DEG:
            moveouts, amps, amps_3d = [], [], []
            for side in (-1, 1):
                x = m.flank_x(r, angle, side)
                if not xs.min() <= x <= xs.max():
                    continue
                j = int(np.argmin(np.abs(xs - x)))
                tj = m.predicted_ns(truth, xs[j], r)
                tf, vf = m.pick(env_f[j], tj, 0.5 * period, dt)
                to, vo = m.pick(env_o[j], tj, 0.5 * period, dt)
                moveouts.append((to - row.t_ours) - (tf - row.t_fdtd))
                amps.append((vo / ao) / (vf / af))
                amps_3d.append(amps[-1] / math.sqrt(travel / (tj - float(truth["source_peak_ns"]))))
            row.moveout[angle] = float(np.mean(moveouts)) if moveouts else math.nan
            row.flank_amp[angle] = float(np.median(amps)) if amps else math.nan
            row.flank_amp_3d[angle] = float(np.median(amps_3d)) if amps_3d else math.nan
        rows.append(row)
    notes = []
    if truth["slab_bottom_m"]:
        notes.append(f"slab bottom {truth['slab_bottom_m']} m over {below_of(name)}")
    if stones_of(name):
        notes.append(f"{stones_of(name)} stones (not in ours)")
    if debye:
        notes.append("Debye")
    return SceneResult(name, truth["half"], f, ", ".join(notes), m.ncc(b, a), ncc_env, lag * dt, shifted, polarity,
                       d_corr, d_lag * dt, (m.dominant_mhz(med_f, dt), m.dominant_mhz(med_o, dt)), f_apex,
                       apex_corr, rows)


def _f(value: float, digits: int = 2) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _median(values: list[float]) -> float:
    good = [v for v in values if math.isfinite(v)]
    return statistics.median(good) if good else math.nan


def scene_table(results: list[SceneResult]) -> list[str]:
    """The per-scene markdown table, with a median row."""
    head = ["scene", "half", "MHz", "sign", "ncc", "ncc env", "shift ns", "ncc shifted", "direct corr", "direct lag ns",
            "f direct F/O", "f apex F/O", "apex corr", "notes"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in results:
        lines.append(f"| {s.name} | {s.half} | {s.frequency_mhz:g} | {s.polarity:+.0f} | {_f(s.ncc)} | "
                     f"{_f(s.ncc_env)} | {_f(s.shift_ns, 3)} | {_f(s.ncc_shifted)} | {_f(s.direct_corr)} | "
                     f"{_f(s.direct_lag_ns, 3)} | "
                     f"{s.f_direct[0]:.0f}/{s.f_direct[1]:.0f} | {_f(s.f_apex[0], 0)}/{_f(s.f_apex[1], 0)} | "
                     f"{_f(s.apex_corr)} | {s.notes} |")

    def med(get: Any, digits: int = 2) -> str:
        return _f(_median([get(s) for s in results]), digits)

    def rel(get: Any) -> str:
        return med(lambda s: get(s)[0] / s.frequency_mhz) + "/" + med(lambda s: get(s)[1] / s.frequency_mhz) + " × f"

    lines.append(f"| **median** | | | | {med(lambda s: s.ncc)} | {med(lambda s: s.ncc_env)} | "
                 f"{med(lambda s: s.shift_ns, 3)} | {med(lambda s: s.ncc_shifted)} | {med(lambda s: s.direct_corr)} | "
                 f"{med(lambda s: s.direct_lag_ns, 3)} | {rel(lambda s: s.f_direct)} | {rel(lambda s: s.f_apex)} | "
                 f"{med(lambda s: s.apex_corr)} | |")
    return lines


def reflector_table(rows: list[ReflectorRow]) -> list[str]:
    """The per-reflector markdown table."""
    a1, a2 = m.ANGLES_DEG
    head = ["scene", "target", "r mm", "depth mm", "t apex FDTD", "Δt apex O−F", "amp/direct O/F", "amp/first O/F",
            "… 3D-corrected", f"Δmoveout {a1:g}°", f"Δmoveout {a2:g}°", f"flank amp {a1:g}° O/F",
            f"flank amp {a2:g}° O/F"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append(f"| {r.scene} | {r.what} | {r.radius_m * 1e3:.1f} | {r.depth_m * 1e3:.0f} | {_f(r.t_fdtd)} | "
                     f"{_f(r.dt_apex, 3)} | {_f(r.amp_vs_direct)} | {_f(r.amp_vs_first)} | {_f(r.amp_vs_first_3d)} | "
                     f"{_f(r.moveout.get(a1, math.nan), 3)} | {_f(r.moveout.get(a2, math.nan), 3)} | "
                     f"{_f(r.flank_amp.get(a1, math.nan))} | {_f(r.flank_amp.get(a2, math.nan))} |")
    return lines


def by_target_table(rows: list[ReflectorRow]) -> list[str]:
    """Medians per target kind and fill."""
    a1, a2 = m.ANGLES_DEG
    head = ["target", "n", "Δt apex O−F ns", "amp/direct O/F", "amp/first O/F (3D-corr.)", f"Δmoveout {a1:g}° ns",
            f"Δmoveout {a2:g}° ns", f"flank amp {a1:g}° O/F (3D-corr.)", f"flank amp {a2:g}° O/F (3D-corr.)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    groups: dict[str, list[ReflectorRow]] = {}
    for r in rows:
        groups.setdefault(r.what, []).append(r)
    groups["all"] = rows
    for what, g in groups.items():
        lines.append(f"| {what} | {len(g)} | {_f(_median([r.dt_apex for r in g]), 3)} | "
                     f"{_f(_median([r.amp_vs_direct for r in g]))} | {_f(_median([r.amp_vs_first for r in g]))} "
                     f"({_f(_median([r.amp_vs_first_3d for r in g]))}) | "
                     f"{_f(_median([r.moveout.get(a1, math.nan) for r in g]), 3)} | "
                     f"{_f(_median([r.moveout.get(a2, math.nan) for r in g]), 3)} | "
                     f"{_f(_median([r.flank_amp.get(a1, math.nan) for r in g]))} "
                     f"({_f(_median([r.flank_amp_3d.get(a1, math.nan) for r in g]))}) | "
                     f"{_f(_median([r.flank_amp.get(a2, math.nan) for r in g]))} "
                     f"({_f(_median([r.flank_amp_3d.get(a2, math.nan) for r in g]))}) |")
    return lines


def residual_table(results: list[SceneResult]) -> list[str]:
    """The residual in one row (medians): the figures each simulator fix is measured by."""
    rows = [r for s in results for r in s.rows]
    a1, a2 = m.ANGLES_DEG

    def med(values: list[float], digits: int = 2) -> str:
        return _f(_median(values), digits)

    pvc = [r.amp_vs_direct for r in rows if r.what == "pipe pvc-air"]
    metal = [r.amp_vs_direct for r in rows if r.what == "pipe metal"]
    pvc_vs_metal = _median(pvc) / _median(metal) if pvc and metal else math.nan
    log_amp = [math.log(r.amp_vs_direct) for r in rows if math.isfinite(r.amp_vs_direct) and r.amp_vs_direct > 0]
    head = ["ncc", "ncc env", "ncc shifted", "shift ns", "apex corr", "Δt apex ns", "amp/direct O/F",
            "std log amp/direct", "amp/first 3D O/F", f"flank {a1:g}° O/F", f"flank {a2:g}° O/F",
            "multiple/primary O", "multiple/primary F", "pvc-air/metal O/F"]
    line = [med([s.ncc for s in results]), med([s.ncc_env for s in results]),
            med([s.ncc_shifted for s in results]), med([s.shift_ns for s in results], 3),
            med([s.apex_corr for s in results]), med([r.dt_apex for r in rows], 3),
            med([r.amp_vs_direct for r in rows]), _f(float(np.std(log_amp)) if log_amp else math.nan),
            med([r.amp_vs_first_3d for r in rows]), med([r.flank_amp.get(a1, math.nan) for r in rows]),
            med([r.flank_amp.get(a2, math.nan) for r in rows]), med([r.multiple[0] for r in rows], 3),
            med([r.multiple[1] for r in rows], 3), _f(pvc_vs_metal)]
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head), "| " + " | ".join(line) + " |"]


def commit() -> str:
    """The short commit of the working tree, marked dirty when it has changes."""
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha


def kept_findings(path: Path) -> str:
    """The hand-written findings of an existing report (between the markers), or a placeholder."""
    if path.exists():
        text = path.read_text()
        if FINDINGS[0] in text and FINDINGS[1] in text:
            return text.split(FINDINGS[0], 1)[1].split(FINDINGS[1], 1)[0].strip("\n")
    return "(findings to be written)"


def report(results: list[SceneResult], findings: str, sha: str, what: str = "") -> str:
    """The markdown report: findings, per-scene table, per-target medians, per-reflector table."""
    rows = [r for s in results for r in s.rows]
    parts = [
        "# gprbot's forward model against the gprMax FDTD scenes",
        "",
        f"Generated by `python -m validation.calibration` at commit `{sha}` over {len(results)} FDTD scenes "
        f"({len(rows)} targets){what}. O = ours (`gprbot.sim`), F = FDTD (gprMax 4.0.1, 2D TMz). "
        "Both B-scans on one time axis (aligned on the transmit instant = the source's peak); our receiver "
        "wow and noise removed. `ncc`: normalised correlation after removing the mean trace and scaling to "
        "unit rms; `ncc env`: the same on the envelopes; `shift`: the best single global time shift "
        "(positive: ours late) and the ncc after it. Picks are envelope peaks within ±0.5 period of the "
        "refracted straight-ray time. Amplitude ratios are (ours/FDTD) of a target's envelope peak "
        "relative to the direct wave's peak (`amp/direct`) or to the scene's first target (`amp/first`); "
        "`3D-corrected` divides out the FDTD's line-source spreading (×sqrt(t_first/t)). Δmoveout: "
        "(t_flank − t_apex) ours minus FDTD at the trace whose ray leaves the target at that angle.",
        "",
        FINDINGS[0],
        findings,
        FINDINGS[1],
        "",
        "## Residual (medians over the scenes and targets below)",
        "",
        *residual_table(results),
        "",
        "## Per scene",
        "",
        *scene_table(results),
        "",
        "## Per target kind (medians)",
        "",
        *by_target_table(rows),
        "",
        "## Per target",
        "",
        *reflector_table(rows),
        "",
    ]
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    """Compare every FDTD scene (or one) and write the report."""
    ap = argparse.ArgumentParser(prog="python -m validation.calibration", description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="one scene name")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the markdown report (default: %(default)s)")
    ap.add_argument("--png", type=Path, help="also write FDTD|ours pictures into this folder")
    ap.add_argument("--half", choices=("dev", "test"), help="only the scenes of one half of the split")
    ap.add_argument("--phase", type=float, default=0.0, help="render ours with this wavelet phase rotation (deg)")
    ap.add_argument("--peak-factor", type=float, default=1.0, help="… and the wavelet peaking at this × f")
    ap.add_argument("--footprint", type=float, default=None, help="… and this footprint power (default: ours)")
    args = ap.parse_args(argv)
    names = [args.only] if args.only else scene_names()
    if args.half:
        names = [n for n in names if load_fdtd(n)[1]["half"] == args.half]
    variation = SignalVariation(phase_deg=args.phase, peak_factor=args.peak_factor)
    if args.footprint is not None:
        variation = replace(variation, footprint_power=args.footprint)
    what = "" if variation.is_identity else (
        f", ours with the wavelet rotated {variation.phase_deg:g}°, peaking at {variation.peak_factor:g} f, "
        f"footprint cos^{variation.footprint_power:g}")
    what += f", {args.half} half only" if args.half else ""
    results = []
    for name in names:
        results.append(compare(name, None if variation.is_identity else variation))
        s = results[-1]
        print(f"{name}: ncc {s.ncc:.2f} (env {s.ncc_env:.2f}), shift {s.shift_ns:+.3f} ns -> {s.ncc_shifted:.2f}")
        if args.png:
            picture(name, args.png)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(report(results, kept_findings(args.out), commit(), what))
    print("\n".join(residual_table(results)))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
