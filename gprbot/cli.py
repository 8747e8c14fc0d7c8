"""The `gprbot` command: demo, run, shell, pull, replay, interpret, info, convert, export-mcap, config check.

Exit codes: 0 success, 1 a runtime error (bad file, unreachable robot, failed shell command), 2 a usage
error (argparse), 3 `demo --check` out of bounds, 130 interrupted. `--json` prints one JSON document on
stdout and nothing else there; progress bars go to stderr, and only to a terminal.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gprbot import __version__, progress
from gprbot.errors import GprbotError, UsageError

if TYPE_CHECKING:
    from gprbot.apps.offline_demo import DemoResult
    from gprbot.config import Config
    from gprbot.gpr.chain.calibrate import KnownTop


def _cmd_demo(args: argparse.Namespace) -> int:
    from gprbot.apps.offline_demo import run_demo
    from gprbot.config import load_config
    from gprbot.sim.scene import builtin_scene_names, load_scene

    cfg = load_config(args.config)
    if not args.offline and args.scene != "all":
        return _demo_via_daemon(cfg, args)
    names = builtin_scene_names() if args.scene == "all" else [args.scene or cfg.sim.scene]
    base = Path(args.out) if args.out else Path(cfg.runs_dir) / time.strftime("demo-%Y%m%d-%H%M%S")
    all_ok = True
    summaries = []
    for name in names:
        scene = load_scene(name)
        out_dir = base / scene.name if len(names) > 1 else base
        demo = run_demo(cfg, scene, out_dir)
        r = demo.result
        summaries.append(_demo_summary(scene.name, demo))
        if not args.json:
            v_note = "estimated from the hyperbolas" if r.velocity_estimated else "from the configured eps_r"
            print(f"scene {scene.name}: {len(r.lines)} lines, {len(r.reconstruction.pipes)} pipes found, "
                  f"velocity {r.velocity_m_per_ns:.4f} m/ns ({v_note}), {demo.seconds:.1f} s")
            print(demo.table)
            print(f"within bounds (3 cm position and depth, 30 % diameter): {'yes' if demo.ok else 'NO'}")
            print(f"results: {out_dir}\n")
        all_ok &= demo.ok
    if args.json:
        print(json.dumps({"scenes": summaries, "all_within_bounds": all_ok}, indent=2))
    return 0 if all_ok else 3  # a failed truth check is a failed demo (--check kept for old scripts)


def _demo_summary(scene: str, demo: DemoResult) -> dict[str, Any]:
    """One scene's demo as plain data (for --json)."""
    import dataclasses

    r = demo.result
    return {
        "scene": scene, "out_dir": str(demo.out_dir),
        "lines": len(r.lines), "pipes_found": len(r.reconstruction.pipes),
        "velocity_m_per_ns": round(r.velocity_m_per_ns, 5), "velocity_estimated": r.velocity_estimated,
        "seconds": round(demo.seconds, 2), "within_bounds": demo.ok,
        "matches": [{k: v for k, v in dataclasses.asdict(m).items() if isinstance(v, int | float | str | None)}
                    for m in demo.matches],
        "extra_pipes": list(demo.extras),
    }


def _demo_via_daemon(cfg: Config, args: argparse.Namespace) -> int:
    import asyncio
    import dataclasses

    from gprbot.apps.daemon_demo import survey_via_shell
    from gprbot.apps.offline_demo import survey_region
    from gprbot.outputs.pipes_json import read_pipes_json
    from gprbot.sim.scene import load_scene
    from gprbot.simulated.evaluation import compare_to_truth, format_truth_table, within_bounds

    if args.scene:
        cfg = dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, scene=args.scene))
    scene = load_scene(cfg.sim.scene)  # a bad scene is one clear error before any daemon starts
    dest = Path(args.out) if args.out else Path(cfg.runs_dir) / time.strftime("pulled-%Y%m%d-%H%M%S")
    talk = sys.stderr if args.json else sys.stdout  # with --json, stdout is the JSON document alone
    print(f"starting the daemon on the simulated robot ({cfg.survey.lines} lines; it drives in real time)", file=talk)
    result = asyncio.run(survey_via_shell(cfg, dest, on_event=lambda e: print(f"* {e}", file=talk, flush=True),
                                          on_console=lambda url: print(f"follow it live: {url}", file=talk,
                                                                       flush=True)))
    print(f"run {result.run}: pulled {len(result.pulled)} files over the shell into {dest}", file=talk)
    # The operator's copy of pipes.json, judged against the simulated scene's truth.
    found = read_pipes_json(dest / "pipes.json")
    matches, extras = compare_to_truth(found, scene, survey_region(cfg))
    ok = within_bounds(matches)
    if args.json:
        print(json.dumps({"run": result.run, "out_dir": str(dest), "pulled": len(result.pulled), "scene": scene.name,
                          "pipes_found": len(found), "within_bounds": ok, "extra_pipes": list(extras),
                          "matches": [dataclasses.asdict(m) for m in matches]}, indent=2))
    else:
        print(format_truth_table(matches, extras, found))
        print(f"within bounds (3 cm position and depth, 30 % diameter): {'yes' if ok else 'NO'}")
    if result.exit_status != 0:
        return result.exit_status
    return 0 if ok else 3


def _cmd_info(args: argparse.Namespace) -> int:
    from gprbot.gpr.formats import detect_format, read_radargram

    if detect_format(args.file) == "dzt":  # DZT keeps its own, richer output (marks, sidecars, gain)
        from gprbot.gpr.dzt import dzt_info, format_dzt_info, read_dzt

        dzt = read_dzt(args.file, allow_partial=args.allow_partial)
        print(json.dumps(dzt_info(dzt), indent=2, default=str) if args.json else format_dzt_info(dzt))
        return 0
    from gprbot.gpr.formats.info import format_radargram_info, radargram_info

    rg = read_radargram(args.file, allow_partial=args.allow_partial)
    print(json.dumps(radargram_info(rg), indent=2, default=str) if args.json else format_radargram_info(rg))
    return 0


def _known_top(text: str) -> KnownTop:
    """--known-top X:DEPTH, in metres."""
    from gprbot.gpr.chain.calibrate import KnownTop

    try:
        x, depth = (float(part) for part in text.split(":"))
        return KnownTop(x, depth)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected X:DEPTH in metres, e.g. 0.55:0.08 (got {text!r}; {exc})") from exc


def _site_top(text: str) -> tuple[float, float, float]:
    """--known-top X,Y:DEPTH (replay): a target's top in the site frame and its depth below the surface, metres."""
    from gprbot.config_ranges import KNOWN_TOP_MAX_DEPTH_M

    try:
        where, depth = text.split(":")
        x, y = (float(part) for part in where.split(","))
        top = (x, y, float(depth))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected X,Y:DEPTH in metres (site frame), e.g. 0.85,0.40:0.06 "
                                         f"(got {text!r}; {exc})") from exc
    if not all(math.isfinite(v) for v in top) or not 0.0 < top[2] <= KNOWN_TOP_MAX_DEPTH_M:
        raise argparse.ArgumentTypeError(f"expected finite X,Y and a depth in (0, {KNOWN_TOP_MAX_DEPTH_M:g}] m, "
                                         f"got {text!r}")
    return top


def _cmd_interpret(args: argparse.Namespace) -> int:
    from gprbot.apps.interpret_file import interpret_file

    out = Path(args.out) if args.out else None
    config = None
    if args.config:
        from gprbot.config import load_config

        config = load_config(args.config)
    from gprbot.apps.interpret_file import default_out_dir, interpret_file_json

    out = out or default_out_dir(Path(args.file), config)
    report = interpret_file(
        Path(args.file), out, args.velocity, args.channel, args.frequency, args.spacing, args.allow_partial,
        height_m=args.height, offset_m=args.offset, config=config, known_tops=args.known_top or (),
    )
    print(json.dumps(interpret_file_json(out), indent=2) if args.json else report)
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    import dataclasses

    from gprbot.gpr.antennas import antenna_frequency_mhz
    from gprbot.gpr.formats import read_radargram, write_radargram
    from gprbot.gpr.formats.radargram import uniform_positions

    rg = read_radargram(args.input, channel=args.channel, allow_partial=args.allow_partial)
    if rg.frequency_mhz is None and (mhz := args.frequency or antenna_frequency_mhz(rg.antenna)):
        rg = dataclasses.replace(rg, frequency_mhz=mhz)
    if args.spacing:
        rg = dataclasses.replace(rg, positions_m=uniform_positions(rg.traces, args.spacing))
    written, notes = write_radargram(args.output, rg)
    for note in (*rg.warnings, *notes):
        print(f"note: {note}")
    print(f"{args.input} ({rg.source_format}, {rg.traces} traces × {rg.n_samples} samples) → "
          + ", ".join(str(p) for p in written))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from gprbot.config import load_config
    from gprbot.daemon import run_daemon

    cfg = load_config(args.config)
    return run_daemon(
        cfg,
        shell_host=args.shell_host or cfg.shell.host,
        shell_port=cfg.shell.port if args.shell_port is None else args.shell_port,
        token_file=args.token_file or cfg.shell.token_file,
    )


def _cmd_replay(args: argparse.Namespace) -> int:
    from gprbot.apps.replay import replay_run
    from gprbot.config import load_config

    run_dir = Path(args.run)
    out = Path(args.out) if args.out else run_dir / "replay"
    cfg = load_config(args.config) if args.config else None
    result = replay_run(run_dir, out, cfg, args.known_top or ())
    if args.json:
        summary = json.loads((out / "summary.json").read_text())
        summary.pop("config", None)  # the resolved config is in summary.json; stdout keeps to the results
        print(json.dumps({"out_dir": str(out), **summary}, indent=2))
    else:
        print(f"replayed {run_dir}: {len(result.lines)} lines, {len(result.reconstruction.pipes)} pipes; "
              f"results: {out}")
    return 0


def _cmd_export_mcap(args: argparse.Namespace) -> int:
    from gprbot.exports.mcap_log import export_mcap

    with progress.bar(None, f"{Path(args.run).name}: exporting to MCAP", unit="record") as bar:
        done = export_mcap(Path(args.run), Path(args.out) if args.out else None, on_record=bar.update)
    if args.json:
        print(json.dumps({"mcap": str(done.path), "messages": done.messages, "run_log": done.log_status}, indent=2))
        return 0
    print(f"{done.path}: {sum(done.messages.values())} messages on {len(done.messages)} topics")
    for topic, count in sorted(done.messages.items()):
        print(f"  {topic:24s} {count}")
    if done.log_status.get("torn"):
        print(f"note: the run log is torn ({done.log_status['note']}); exported what precedes the tear")
    return 0


def _cmd_config_check(args: argparse.Namespace) -> int:
    from gprbot.config import load_config, to_dict

    cfg = load_config(args.file)  # the daemon's own loader: the same keys, types and ranges
    if args.json:
        print(json.dumps(to_dict(cfg), indent=2))
        return 0
    devices = "simulated robot" if cfg.simulated else f"motors on {cfg.motors.port}"
    print(f"{args.file}: ok ({devices}; shell {cfg.shell.host}:{cfg.shell.port}; runs in {cfg.runs_dir}; "
          f"interpretation {cfg.interpretation.method}, completion {cfg.reconstruction.completion})")
    return 0


def _cmd_shell(args: argparse.Namespace) -> int:
    from gprbot.shell.interactive import run_shell

    return run_shell(args)


def _cmd_pull(args: argparse.Namespace) -> int:
    from gprbot.shell.interactive import run_pull

    return run_pull(args)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the `gprbot` command."""
    parser = argparse.ArgumentParser(prog="gprbot", description="GPR inspection robot: survey, interpret, model.")
    parser.add_argument("--version", action="version", version=f"gprbot {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars (they only go to a terminal)")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser(
        "demo",
        help="a whole simulated survey: by default the operator's path — start the daemon on the simulated "
        "robot, survey through its TCP shell, pull the results, compare with the scene's truth",
    )
    demo.add_argument("--scene", help="built-in scene name, a scene YAML file, or 'all' (default: config's)")
    demo.add_argument("--out", help="run directory to write (default: runs/demo-<time>)")
    demo.add_argument("--config", help="config YAML (default: the embedded simulation config)")
    demo.add_argument("--offline", action="store_true",
                      help="process the simulated survey directly (fast, no daemon); implied by --scene all")
    demo.add_argument("--check", action="store_true",
                      help="(the default now) exit 3 unless every pipe is within the bounds")
    demo.add_argument("--json", action="store_true", help="print the summary as JSON (the rest goes to stderr)")
    demo.set_defaults(func=_cmd_demo)

    info = sub.add_parser("info", help="print the header of a GPR file (DZT, DT1+HD, RD3/RD7+RAD, SEG-Y, SU, gprMax)")
    info.add_argument("file")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.add_argument("--allow-partial", action="store_true", help="drop a trailing partial scan (a cut file)")
    info.set_defaults(func=_cmd_info)

    interp = sub.add_parser("interpret", help="interpret one B-scan (any GPR file `info` reads) into pipe detections")
    interp.add_argument("file")
    velocity = interp.add_mutually_exclusive_group()
    velocity.add_argument("--velocity", type=float, help="wave velocity in m/ns (default: estimated)")
    velocity.add_argument("--known-top", type=_known_top, metavar="X:DEPTH", action="append",
                          help="calibrate the velocity on a target whose top lies DEPTH m below the surface at "
                               "X m along the line (a cover meter reading, a core): e.g. 0.55:0.08; twice, at "
                               "depths two periods apart in time, it fixes time zero too")
    interp.add_argument("--channel", type=int, default=0, help="channel of a multi-channel file")
    interp.add_argument("--allow-partial", action="store_true", help="drop a trailing partial scan (a cut file)")
    interp.add_argument("--frequency", type=float, help="antenna centre frequency in MHz (default: from header)")
    interp.add_argument("--spacing", type=float, help="trace spacing in m (default: from the header's traces/m)")
    interp.add_argument("--height", type=float, help="antenna height above the surface in m (default: 0)")
    interp.add_argument("--offset", type=float, help="Tx-Rx separation in m (default: from the file or antenna)")
    interp.add_argument("--config", help="config YAML (interpretation.method: chain/classical or migrationnet)")
    interp.add_argument("--out", help="directory for detections.json and PNGs (default: beside runs/)")
    interp.add_argument("--json", action="store_true", help="print detections.json instead of the report")
    interp.set_defaults(func=_cmd_interpret)

    convert = sub.add_parser("convert", help="convert a GPR file (any format `info` reads) to .DZT, .DT1, .sgy or .su")
    convert.add_argument("input")
    convert.add_argument("output", help="the output file; its suffix picks the format (.DZT, .DT1, .sgy/.segy, .su)")
    convert.add_argument("--channel", type=int, default=0, help="channel of a multi-channel DZT file")
    convert.add_argument("--frequency", type=float, help="antenna centre frequency in MHz, when the input lacks it")
    convert.add_argument("--spacing", type=float, help="trace spacing in m, replacing the input's positions")
    convert.add_argument("--allow-partial", action="store_true", help="drop a trailing partial trace (a cut file)")
    convert.set_defaults(func=_cmd_convert)

    run = sub.add_parser("run", help="run the robot daemon (the simulated robot unless the config names devices)")
    run.add_argument("--config", help="config YAML (default: the embedded simulation config)")
    run.add_argument("--shell-host", help="override shell.host")
    run.add_argument("--shell-port", type=int, help="override shell.port (0: any free port)")
    run.add_argument("--token-file", help="override shell.token_file")
    run.set_defaults(func=_cmd_run)

    replay = sub.add_parser("replay", help="reprocess a recorded run offline (fusion + interpretation)")
    replay.add_argument("run", help="the run directory (holding log-000.msgpack ...)")
    replay.add_argument("--out", help="where to write the results (default: RUN/replay)")
    replay.add_argument("--config", help="override the config recorded in the run's header")
    replay.add_argument("--known-top", type=_site_top, metavar="X,Y:DEPTH", action="append",
                        help="a target whose top lies DEPTH m below the surface at site (X, Y) m (a cover meter, a "
                             "core): the survey's velocity is calibrated on it instead of estimated (repeatable)")
    replay.add_argument("--json", action="store_true", help="print the summary as JSON")
    replay.set_defaults(func=_cmd_replay)

    export = sub.add_parser("export-mcap", help="write a run's log as MCAP (Foxglove and other robotics tools)")
    export.add_argument("run", help="the run directory (holding log-000.msgpack ...)")
    export.add_argument("--out", help="the MCAP file to write (default: RUN/run.mcap)")
    export.add_argument("--json", action="store_true", help="print what was written as JSON")
    export.set_defaults(func=_cmd_export_mcap)

    config = sub.add_parser("config", help="configuration tools")
    config_sub = config.add_subparsers(dest="config_command", required=True)
    check = config_sub.add_parser("check", help="load a config file as the daemon would; exit 1 naming the bad key")
    check.add_argument("file")
    check.add_argument("--json", action="store_true", help="print the resolved config (defaults filled in) as JSON")
    check.set_defaults(func=_cmd_config_check)

    from gprbot.shell.interactive import add_pull_arguments, add_shell_arguments

    shell = sub.add_parser("shell", help="talk to a robot's command shell (HOST[:PORT], --token-file)")
    add_shell_arguments(shell)
    shell.set_defaults(func=_cmd_shell)
    pull = sub.add_parser("pull", help="download a run's files from a robot, sha256-checked")
    add_pull_arguments(pull)
    pull.set_defaults(func=_cmd_pull)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: one clear error line and a non-zero exit for bad input, never a traceback."""
    parser = build_parser()
    args = parser.parse_args(argv)  # a usage error exits 2 here (argparse)
    progress.set_quiet(args.quiet)
    try:
        return int(args.func(args))
    except GprbotError as exc:
        if args.debug:
            raise
        print(f"gprbot: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, UsageError) else 1
    except KeyboardInterrupt:
        print("gprbot: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
