"""`gprbot interpret`: one B-scan from any GPR file (DZT, DT1, RD3, SEG-Y, SU, gprMax) → detections.json and PNGs."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from gprbot.config import Config, GprConfig, InterpretationConfig, load_config
from gprbot.errors import DataFormatError, GprbotError, UsageError
from gprbot.gpr.antennas import GSSI_ANTENNAS, antenna_frequency_mhz, check_frequency_mhz
from gprbot.gpr.bscan import BScan, CrossSection, Detection
from gprbot.gpr.chain.calibrate import KnownTop
from gprbot.gpr.chain.classify import ClassifiedDetection
from gprbot.gpr.chain.run import interpret
from gprbot.gpr.chain.sizing import BLOB_RADIUS_REL_SIGMA
from gprbot.gpr.formats import Radargram, read_radargram
from gprbot.gpr.preprocess import preprocess
from gprbot.gpr.render import write_bscan_png, write_cross_section_png
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.confirm import confirmed_section
from gprbot.outputs.pipes_json import write_json_atomic

__all__ = [
    "GSSI_ANTENNAS", "antenna_frequency_mhz", "file_bscan", "gpr_config_for", "interpret_dzt", "interpret_file",
    "radargram_bscan",
]

# A GSSI ground-coupled antenna rides on the surface; its Tx–Rx spacing is a fraction of a
# wavelength in air. These are approximations for the travel-time model, not vendor figures.
DEFAULT_OFFSET_M = {100: 0.5, 200: 0.3, 270: 0.25, 400: 0.16, 500: 0.12, 900: 0.06}
# detections.json's "radius_from", and the mark the text report puts after such a radius
RADIUS_FROM = {"fit": "hyperbola fit", "survey": "the survey's lines", "migrationnet": "MigrationNet pipe mask",
               "none": "not measured: the middle of what the hyperbola allows"}
RADIUS_MARK = {RADIUS_FROM["migrationnet"]: " (mask)", RADIUS_FROM["none"]: " (?)"}
FILL_HINT = {"slower": "metal, water or wet (slower than the host)", "faster": "air-filled or a void (faster)"}


def gpr_config_for(rg: Radargram, base: GprConfig, frequency_mhz: float | None) -> GprConfig:
    """The acquisition settings of a file expressed as a GprConfig (frequency from the file or its antenna name)."""
    if frequency_mhz is not None and (problem := check_frequency_mhz(frequency_mhz)) is not None:
        raise DataFormatError(f"--frequency: {problem}; give the antenna's centre frequency in MHz")
    mhz = frequency_mhz or rg.frequency_mhz or antenna_frequency_mhz(rg.antenna)
    if mhz is None:
        raise DataFormatError(
            f"cannot tell the antenna's centre frequency from the file (antenna {rg.antenna!r}); pass --frequency MHZ"
        )
    offset = rg.antenna_separation_m
    if offset is None:
        offset = next((v for f, v in sorted(DEFAULT_OFFSET_M.items()) if mhz <= f), 0.05)
    return replace(
        base,
        centre_frequency_mhz=mhz,
        samples=rg.n_samples,
        time_window_ns=rg.window_ns,
        pre_trigger_ns=float("nan") if rg.time_zero_ns is None else rg.time_zero_ns,
        antenna_height_m=0.0,
        tx_rx_offset_m=offset,
        eps_r=None,
    )


def radargram_bscan(rg: Radargram, spacing_m: float | None, source: str = "the file") -> BScan:
    """A Radargram as a B-scan along x: positions from the file, or `spacing_m` apart when given."""
    if rg.traces == 0:
        raise DataFormatError(f"{source}: the file holds no traces")
    n = rg.traces
    positions = np.zeros((n, 3))
    if spacing_m:
        positions[:, 0] = np.arange(n) * spacing_m
    elif rg.positions_m is not None:
        positions[:, 0] = rg.positions_m - rg.positions_m[0]
    else:
        raise DataFormatError(f"{source}: the file has no distance calibration; pass --spacing M")
    t0 = float("nan") if rg.time_zero_ns is None else rg.time_zero_ns
    return BScan(rg.samples, rg.dt_ns, t0, positions, np.zeros(n))


def file_bscan(
    path: Path, channel: int, spacing_m: float | None, allow_partial: bool = False
) -> tuple[BScan, Radargram]:
    """The traces of one channel of any GPR file as a B-scan along x, with the file's Radargram."""
    rg = read_radargram(path, channel=channel, allow_partial=allow_partial)
    return radargram_bscan(rg, spacing_m, str(path)), rg


def _antenna_geometry(gpr: GprConfig, height_m: float | None, offset_m: float | None) -> tuple[GprConfig, str]:
    """The antenna geometry to interpret with (the options override the file/table values) and where it came from."""
    if height_m is not None and not 0.0 <= height_m <= 1.0:
        raise UsageError(f"--height {height_m:g} m: give the antenna's height above the surface, 0 to 1 m")
    if offset_m is not None and not 0.0 <= offset_m <= 5.0:
        raise UsageError(f"--offset {offset_m:g} m: give the Tx-Rx separation, 0 to 5 m")
    origin = "options" if height_m is not None or offset_m is not None else "file or antenna table"
    return replace(gpr, antenna_height_m=gpr.antenna_height_m if height_m is None else height_m,
                   tx_rx_offset_m=gpr.tx_rx_offset_m if offset_m is None else offset_m), origin


def _detection_json(d: ClassifiedDetection) -> dict[str, object]:
    """One detection as detections.json lists it."""
    return {
        "x_m": round(d.x_m, 4), "depth_m": round(d.depth_m, 4), "cover_m": round(d.fit.top_m, 4),
        "radius_m": round(d.radius_m, 4), "radius_sigma_m": round(d.radius_sigma_m, 4),
        "radius_supported": d.radius_supported, "radius_from": RADIUS_FROM[d.radius_source],
        "contrast": d.contrast, "fill_hint": FILL_HINT[d.contrast],
        "confidence": round(d.confidence, 3), "picks": d.fit.n_picks, "found_by": d.found_by,
    }


def _blob_json(d: Detection) -> dict[str, object]:
    """One MigrationNet pipe as detections.json lists it: the chain's keys where a blob has them."""
    return {
        "x_m": round(d.x_m, 4), "depth_m": round(d.depth_m, 4), "cover_m": round(d.depth_m - d.radius_m, 4),
        "radius_m": round(d.radius_m, 4), "radius_sigma_m": round(BLOB_RADIUS_REL_SIGMA * d.radius_m, 4),
        "radius_supported": False, "radius_from": RADIUS_FROM["migrationnet"], "confidence": round(d.score, 3),
        "found_by": "migrationnet",
    }


Sizer = Callable[[float], Sequence[Detection]]


def _sizer(bscan: BScan, gpr: GprConfig, cfg: Config) -> tuple[Sizer | None, list[str]]:
    """MigrationNet's blobs for the radii the chain's curves do not measure, and a note if it cannot be had."""
    from gprbot.infer.pipeline import migrationnet_sizer

    try:
        return migrationnet_sizer(bscan, replace(cfg, gpr=gpr)), []
    except GprbotError as exc:
        return None, [f"radii the hyperbolas do not measure are left unmeasured: {exc}"]


def _migrationnet_section(bscan: BScan, gpr: GprConfig, cfg: InterpretationConfig, v: float) -> CrossSection:
    """MigrationNet's section of the B-scan at velocity v (the configured learned interpreter)."""
    from gprbot.infer.pipeline import migrationnet_interpreter

    net = migrationnet_interpreter(cfg.migrationnet_model, 2)
    return net.interpret(preprocess(bscan, gpr), gpr, cfg, v)


def shown_bscan(bscan: BScan, gpr: GprConfig, t0_ns: float) -> BScan:
    """The B-scan as bscan.png shows it: preprocessed at the chain's time zero (not a second estimate of it)."""
    return preprocess(replace(bscan, t0_ns=t0_ns), gpr)


def default_out_dir(path: Path, config: Config | None = None) -> Path:
    """Where `gprbot interpret FILE` writes without --out: runs_dir/interpret-<stem>-<time>."""
    cfg = config or load_config()
    return Path(cfg.runs_dir) / time.strftime(f"interpret-{path.stem}-%Y%m%d-%H%M%S")


def interpret_file(
    path: Path,
    out_dir: Path | None,
    velocity: float | None,
    channel: int = 0,
    frequency_mhz: float | None = None,
    spacing_m: float | None = None,
    allow_partial: bool = False,
    *,
    height_m: float | None = None,
    offset_m: float | None = None,
    config: Config | None = None,
    known_tops: Sequence[KnownTop] = (),
) -> str:
    """Interpret a GPR file of any format, write detections.json and PNGs, and return a printable report.

    The configured `interpretation.method` decides: "chain" and "classical" are the interpretation chain
    (gprbot.gpr.chain: pipes and rebars, velocity estimated from the hyperbolas; the survey's classical
    interpreter needs its other lines, and on single files the chain measures better: validation/REPORT.md);
    "migrationnet" is the learned model on the section migrated at the chain's (or the given) velocity.
    """
    cfg = config or load_config()
    bscan, rg = file_bscan(path, channel, spacing_m, allow_partial)
    # A reader's advice to pass an option the user has passed is noise.
    given = {"--spacing": spacing_m, "--frequency": frequency_mhz,
             "--velocity": velocity if velocity is not None else (known_tops or None)}
    notes = [w for w in rg.warnings if not any(opt in w and value is not None for opt, value in given.items())]
    gpr, geometry_origin = _antenna_geometry(gpr_config_for(rg, cfg.gpr, frequency_mhz), height_m, offset_m)
    eps_r = float(rg.header.get("eps_r") or 0.0) if rg.source_format == "dzt" else 0.0
    fallback = velocity_from_eps(eps_r) if eps_r > 1.0 else None
    out = out_dir or default_out_dir(path, cfg)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    sizer, sizer_note = _sizer(bscan, gpr, cfg)
    result = interpret(bscan, gpr, velocity, fallback_velocity_m_per_ns=fallback, known_tops=known_tops, sizer=sizer)
    notes += list(result.notes) + sizer_note
    if result.velocity_source == "estimated":
        # One hyperbola's curve cannot give the velocity to a few per cent while its radius is unknown
        # (validation.hyperbola_signatures); a known cover can (validation.known_top).
        notes.append("depths scale with the estimated velocity (FDTD yardstick: median error 11-15 %); a known cover "
                     "calibrates it: --known-top X:DEPTH (median error 5-6 %)")
    method = cfg.interpretation.method
    section = result.section
    pipes = [_detection_json(d) for d in result.pipes]
    if method == "migrationnet":
        interp = replace(cfg.interpretation, depth_max_m=float(section.z_m[-1]))
        net, dropped = confirmed_section(_migrationnet_section(bscan, gpr, interp, result.velocity),
                                         result.detections, result.rebars)
        section = replace(net, rebars=section.rebars)
        pipes = [_blob_json(d) for d in section.detections]
        notes.append("pipes from MigrationNet (interpretation.method: migrationnet); rebars, velocity from the chain")
        notes += [f"MigrationNet's blob at x {d.x_m:.3f} m, depth {d.depth_m:.3f} m not reported: {why}"
                  for d, why in dropped]
    seconds = time.perf_counter() - start
    prep = result.prepared
    write_json_atomic(
        out / "detections.json",
        {
            "file": str(path),
            "channel": channel,
            "format": rg.source_format,
            "antenna": rg.antenna,
            "method": "migrationnet" if method == "migrationnet" else "interpretation chain",
            "centre_frequency_mhz": gpr.centre_frequency_mhz,
            "dominant_frequency_mhz": round(prep.frequency_mhz, 1),
            "antenna_height_m": gpr.antenna_height_m,
            "tx_rx_offset_m": gpr.tx_rx_offset_m,
            "antenna_geometry_from": geometry_origin,
            "time_zero_ns": round(prep.t0_ns, 4),
            "time_zero_from": prep.t0_method,
            "velocity_m_per_ns": round(result.velocity, 5),
            "velocity_sigma_m_per_ns": None if result.velocity_sigma != result.velocity_sigma
            else round(result.velocity_sigma, 5),
            "velocity_source": result.velocity_source,
            "velocity_method": result.velocity_method,
            "velocity_estimated": result.velocity_source == "estimated",
            # each hyperbola's vote (apex x, its time after time zero, the velocity it focuses at, its weight)
            "velocity_votes": [{"x_m": round(b.x_m, 4), "t_ns": round(b.t_ns, 3), "v_m_per_ns": round(b.v, 5),
                                "weight": round(b.weight, 3)} for b in result.velocity_votes],
            "x_origin": "the first trace",
            "depth_origin": "the ground surface (depth of the target's centre, positive down; cover_m to its top)",
            "detections": pipes,
            "rebars": [_detection_json(d) for d in result.rebars],
            "notes": notes,
            "seconds": round(seconds, 3),
        },
    )
    v_text = {"given": "given", "estimated": f"estimated ±{result.velocity_sigma:.4f}, {result.velocity_method}",
              "calibrated": f"±{result.velocity_sigma:.4f}, {result.velocity_method}",
              "fallback": "not estimated"}[result.velocity_source]
    write_bscan_png(out / "bscan.png", shown_bscan(bscan, gpr, prep.t0_ns), result.velocity,
                    v_text, title=path.name, site_frame=False)
    write_cross_section_png(out / "section.png", section, velocity_note=v_text, title=path.name)
    lines = [
        f"{path.name} ({rg.source_format}): {rg.traces} traces × {rg.n_samples} samples, "
        f"{gpr.centre_frequency_mhz:.0f} MHz antenna (reflections peak near {prep.frequency_mhz:.0f} MHz)",
        f"velocity {result.velocity:.4f} m/ns ({v_text}); {len(pipes)} pipes, {len(result.rebars)} rebars "
        f"({seconds:.2f} s):",
    ]
    if len(result.velocity_votes) > 1:  # whether the hyperbolas agree is the first thing to check on a velocity
        lines.append("  votes (m/ns at x m, weight): " + ", ".join(
            f"{b.v:.3f} at {b.x_m:.2f} ({b.weight:.1f})" for b in sorted(result.velocity_votes, key=lambda b: b.v)))
    for d in pipes:
        x, depth, r, conf = (float(str(d[k])) for k in ("x_m", "depth_m", "radius_m", "confidence"))
        radius = f"radius {100 * r:4.1f} cm" + RADIUS_MARK.get(str(d.get("radius_from")), "")
        lines.append(f"  pipe   x {x:6.2f} m  depth {depth:5.2f} m  {radius}  confidence {conf:.2f}")
    for bar in result.rebars:
        lines.append(f"  rebar  x {bar.x_m:6.2f} m  cover {bar.fit.top_m:5.3f} m")
    lines += [f"note: {n}" for n in notes]
    lines.append(f"written: {out}/detections.json, bscan.png, section.png")
    return "\n".join(lines)


def interpret_file_json(out_dir: Path) -> dict[str, object]:
    """The detections.json that interpret_file wrote into out_dir (for `gprbot interpret --json`)."""
    import json

    document: dict[str, object] = json.loads((out_dir / "detections.json").read_text())
    return document


interpret_dzt = interpret_file  # the name before other formats were read
