"""gprMax `.out` (HDF5): root attributes dt (s) and Iterations, fields in /rxs/rxN/{Ex..Hz}, (Iterations, traces).

Merged B-scans (3.x) and the 2015 pre-release layout (only dt and Iterations) are read alike. The file
holds no trace positions: they come from the .in beside it when it states #src_steps/#rx_steps
(antenna models in #python blocks are not executed), and the centre frequency from its #waveform.
"""

from __future__ import annotations

import faulthandler
import multiprocessing as mp
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.radargram import (
    Radargram,
    check_dt,
    check_size,
    plausible_frequency,
    plausible_separation,
    read_text,
    uniform_positions,
)

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
COMPONENTS = ("Ex", "Ey", "Ez", "Hx", "Hy", "Hz")


def _h5py() -> Any:
    try:
        import h5py
    except ImportError as exc:
        raise DataFormatError("reading gprMax .out files needs h5py: pip install gprbot[formats]") from exc
    return h5py


LOAD_TIMEOUT_S = 120.0


def _load(src: str, component: str | None, receiver: str) -> tuple[dict[str, Any], dict[str, Any], int]:
    """The root attributes, the wanted component arrays and the receiver count, read with h5py."""
    h5py = _h5py()
    try:
        with h5py.File(src, "r") as f:
            attrs = {k: _plain(v) for k, v in f.attrs.items()}
            group = f.get(f"rxs/{receiver}")
            if group is None or not isinstance(group, h5py.Group):
                raise DataFormatError(f"{src}: no /rxs/{receiver} group; not a gprMax output file (or no receiver)")
            present = [c for c in COMPONENTS if isinstance(group.get(c), h5py.Dataset)]
            if not present:
                raise DataFormatError(f"{src}: /rxs/{receiver} holds no field component (Ex..Hz)")
            for name in present:
                shape = group[name].shape
                if len(shape) not in (1, 2):
                    raise DataFormatError(f"{src}: {receiver}/{name} has shape {shape}; expected (iterations, traces)")
                check_size(src, shape[1] if len(shape) == 2 else 1, shape[0])
            if component is not None and component not in present:
                have = ", ".join(present)
                raise DataFormatError(f"{src}: component {component!r} is not in the file (it has {have})")
            wanted = [component] if component else [c for c in present if c.startswith("E")] or present
            arrays = {c: np.asarray(group[c][...], dtype=np.float32) for c in wanted}
            return attrs, arrays, len(f["rxs"])
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:  # what h5py raises on damaged files
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataFormatError(f"{src}: h5py cannot read it ({why}); the file is damaged or not gprMax output") from exc


def _child(conn: Any, src: str, component: str | None, receiver: str) -> None:
    faulthandler.disable()  # a crash here is expected on damaged files and reported by the parent
    try:
        conn.send(_load(src, component, receiver))
    except DataFormatError as exc:
        conn.send(str(exc))
    finally:
        conn.close()


def _load_isolated(src: str, component: str | None, receiver: str) -> tuple[dict[str, Any], dict[str, Any], int]:
    """`_load` in a forked child: the HDF5 C library can crash on a damaged file, and must not take us along."""
    _h5py()
    if "fork" not in mp.get_all_start_methods():
        return _load(src, component, receiver)
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # 3.12+: fork of a threaded process; the child only reads
        proc = ctx.Process(target=_child, args=(child, src, component, receiver), daemon=True)
        proc.start()
    child.close()
    try:
        result = parent.recv() if parent.poll(LOAD_TIMEOUT_S) else None
    except EOFError:
        result = None
    finally:
        parent.close()
        proc.join(1.0)
        if proc.is_alive():
            proc.kill()
            proc.join()
    if isinstance(result, str):
        raise DataFormatError(result)
    if result is None:
        raise DataFormatError(
            f"{src}: the HDF5 library failed reading it (exit code {proc.exitcode}); the file is damaged, copy it again"
        )
    attrs, arrays, nrx = result
    return attrs, arrays, nrx


def read_gprmax(path: Path, *, component: str | None = None, receiver: str = "rx1") -> Radargram:
    """A gprMax output file: the strongest E component of `receiver` unless `component` names one."""
    src = str(path)
    notes: list[str] = []
    attrs, arrays, nrx = _load_isolated(src, component, receiver)
    if component is None:
        energy = {c: float(np.nansum(np.square(a, dtype=np.float64))) for c, a in arrays.items() if c.startswith("E")}
        component = max(energy, key=lambda c: energy[c]) if energy else next(iter(arrays))
    data = arrays[component]
    data = data[:, None] if data.ndim == 1 else data
    if nrx > 1:
        notes.append(f"{nrx} receivers in the file; read {receiver}")
    dt_s = attrs.get("dt")
    if not isinstance(dt_s, float | int):
        raise DataFormatError(f"{src}: no numeric 'dt' attribute at the root; not a gprMax output file")
    dt = check_dt(src, float(dt_s) * 1e9, data.shape[0])
    iterations = attrs.get("Iterations")
    if isinstance(iterations, int) and iterations != data.shape[0]:
        notes.append(f"Iterations is {iterations}, the {component} dataset has {data.shape[0]} samples")
    samples = np.ascontiguousarray(data.T, dtype=np.float32)
    if not np.isfinite(samples).all():
        notes.append("NaN or infinite samples set to 0")
        samples = np.nan_to_num(samples, nan=0.0, posinf=0.0, neginf=0.0)
    scene = _scene_from_in(path, attrs, samples.shape[0], notes)
    freq = plausible_frequency(scene.pop("frequency_mhz", None), notes, "the .in's waveform")
    sep = plausible_separation(scene.pop("separation_m", None), notes, "the .in's Tx-Rx distance")
    positions = scene.pop("positions", None)
    if positions is None:
        why = "its .in moves the antenna in a #python block, which is not run" if "#python" in scene.pop(
            "in_text", "") else "there is no .in with #src_steps/#rx_steps beside it"
        notes.append(f"trace positions are not in a gprMax .out and {why}; pass --spacing")
    scene.pop("in_text", None)
    header = {"attributes": attrs, "component": component, "receiver": receiver, "components": list(arrays),
              "time_origin": "the source's excitation start", **scene}
    return Radargram(samples=samples, dt_ns=dt, source_format="gprmax", positions_m=positions, frequency_mhz=freq,
                     antenna_separation_m=sep, antenna=scene.get("antenna", ""), header=header, warnings=tuple(notes))


def _plain(value: Any) -> Any:
    """An HDF5 attribute as a plain Python value (numpy scalars and bytes unwrapped)."""
    if isinstance(value, bytes):
        return value.decode("latin-1")
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value.item() if isinstance(value, np.generic) else value


def _find_in_file(path: Path) -> Path | None:
    stem = path.stem
    for cand in (stem, re.sub(r"_(merged|all)$", "", stem), re.sub(r"\d+$", "", stem)):
        p = path.with_name(cand + ".in")
        if cand and p.is_file():
            return p
    return None


def _floats(text: str, command: str) -> list[float] | None:
    m = re.search(rf"^#{command}:\s*(.+)$", text, re.MULTILINE)
    if not m:
        return None
    try:
        return [float(tok) for tok in m.group(1).split() if re.match(r"^[-+0-9.eE]+$", tok)]
    except ValueError:
        return None


def _scene_from_in(path: Path, attrs: dict[str, Any], traces: int, notes: list[str]) -> dict[str, Any]:
    """Positions, frequency and Tx–Rx separation from the gprMax input file beside the output, if any."""
    out: dict[str, Any] = {}
    src_steps, rx_steps = attrs.get("srcsteps"), attrs.get("rxsteps")
    in_path = _find_in_file(path)
    text = ""
    if in_path is not None:
        try:
            text = read_text(in_path, "gprMax input file")
        except DataFormatError as exc:
            notes.append(f"{exc}; ignored")
        out["input_file"] = in_path.name
        out["in_text"] = text
    if src_steps is None and text:
        src_steps, rx_steps = _floats(text, "src_steps"), _floats(text, "rx_steps")
    wave = re.search(r"^#waveform:\s*\S+\s+\S+\s+([-+0-9.eE]+)", text, re.MULTILINE)
    if wave:
        out["frequency_mhz"] = float(wave.group(1)) / 1e6
    model = re.search(r"antenna_like_(GSSI|MALA)_(\d+)", text)
    if model:
        out["antenna"] = f"gprMax antenna_like_{model.group(1)}_{model.group(2)}"
        out.setdefault("frequency_mhz", float(model.group(2)) if model.group(1) == "GSSI" else None)
    tx = next((_floats(text, c) for c in ("hertzian_dipole", "magnetic_dipole", "voltage_source")
               if _floats(text, c)), None)
    rx = _floats(text, "rx")
    if tx and rx and len(tx) >= 3 and len(rx) >= 3:
        tx_xyz, rx_xyz = np.array(tx[-3:]), np.array(rx[:3])
        out["separation_m"] = float(np.linalg.norm(rx_xyz - tx_xyz))
        out["first_midpoint_m"] = ((tx_xyz + rx_xyz) / 2).tolist()
    if isinstance(src_steps, list) and isinstance(rx_steps, list) and len(src_steps) == len(rx_steps) == 3:
        step = float(np.linalg.norm((np.array(src_steps) + np.array(rx_steps)) / 2))
        if 0 < step < 1e3:
            out["positions"] = uniform_positions(traces, step)
    return out
