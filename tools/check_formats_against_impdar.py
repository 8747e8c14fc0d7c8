"""Compare gprbot's readers with readers that are not ours, sample for sample, on the real files in shared/.

Run in a scratch environment that has ImpDAR (never the project's venv):

    python3 -m venv /tmp/scratch-impdar && /tmp/scratch-impdar/bin/pip install impdar==1.2.1
    PYTHONPATH=. /tmp/scratch-impdar/bin/python tools/check_formats_against_impdar.py [DATA_DIR]

References: ImpDAR 1.2.1 for DT1 (load_pe), RD3 (load_ramac) and gprMax (load_gprMax, Ez only, with the
pre-trigger rows it cuts); segyio's Seismic Unix reader for the .su file (ImpDAR's SEG-Y loader needs a
reel header and refuses it); h5py directly for the gprMax component we choose (Ey in the 3D file).
ImpDAR's DT1 loader subtracts each trace's mean over its first 100 samples and stores the result in
int16 (truncating), so our samples are put through the same step before comparing. ImpDAR 1.2.1's
.HD date parser wants MM/DD/YYYY on line 3 and a date on line 5: it is given a copy of the .HD whose
date lines are rewritten (the .DT1 is the original file). The printed result is in docs/formats.md.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import warnings
from pathlib import Path

import h5py
import numpy as np
import segyio

from gprbot.gpr.formats import read_radargram
from gprbot.gpr.formats.gprmax import read_gprmax

warnings.simplefilter("ignore")
from impdar.lib.load import load_gprMax, load_pulse_ekko, load_ramac  # noqa: E402


def row(name: str, reference: str, ours: np.ndarray, ref: np.ndarray, extra: str = "") -> bool:
    """Print one comparison line; True when shapes match and samples are identical."""
    same_shape = ours.shape == ref.shape
    diff = float(np.abs(ours.astype(np.float64) - ref.astype(np.float64)).max()) if same_shape else float("nan")
    print(f"{name:<36} {reference:<30} {ours.shape!s:>12} max|diff| {diff:<10g} {extra}")
    return same_shape and diff == 0.0


def main(data: Path) -> int:
    """Run every comparison; exit status 1 if any differs."""
    ok = True
    dt1 = data / "pulseekko_dt1_rgpr_negative" / "yyline3.DT1"
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / dt1.name
        shutil.copy(dt1, copy)
        lines = [ln for ln in (dt1.with_suffix(".HD")).read_text("latin-1").splitlines() if ln.strip()]
        lines[2] = "10/06/2012"
        lines.insert(4, "2012-10-06")
        copy.with_suffix(".HD").write_text("\n".join(lines) + "\n")
        pe = load_pulse_ekko.load_pe(str(copy))
    rg = read_radargram(dt1)
    raw = rg.samples.astype(np.float64)
    ours = (raw - raw[:, :100].mean(axis=1, keepdims=True)).astype(np.int16)
    pos = float(np.abs(pe.traceheaders.positions[0] - rg.positions_m).max())
    ok &= row("DT1 yyline3 (demeaned as ImpDAR)", "ImpDAR 1.2.1 load_pe", ours, pe.data.T,
              f"dt {rg.dt_ns:g} vs {pe.dt * 1e9:g} ns, positions max|diff| {pos:g} m")

    rd3 = data / "mala_rd3_250mhz_matgpr" / "DAT_0097.rd3"
    ra = load_ramac.load_ramac(str(rd3))
    rg = read_radargram(rd3)
    ok &= row("RD3 DAT_0097", "ImpDAR 1.2.1 load_ramac", rg.samples, ra.data.T,
              f"dt {rg.dt_ns:.9g} vs {ra.dt * 1e9:.9g} ns")

    su = data / "su_trench_pipes_matgpr" / "trench_and_pipes.su"
    with segyio.su.open(str(su), endian="little", ignore_geometry=True) as f:
        ref = np.asarray(f.trace.raw[:])
        ref_dt = float(f.samples[1] - f.samples[0])
    rg = read_radargram(su)
    ok &= row("SU trench_and_pipes", "segyio.su 1.9", rg.samples, ref, f"dt {rg.dt_ns:g} (d1) vs {ref_dt:g} (field)")

    for folder, name in (("gprmax_cylinder_2d", "cylinder_Bscan_2D_merged.out"),
                         ("gprmax_gssi1500_cylinder_3d", "GSSI_1500_cylinder_Bscan_all.out")):
        out = data / folder / name
        gm = load_gprMax.load_gprMax(str(out))
        ez = read_gprmax(out, component="Ez").samples
        cut = ez.shape[1] - gm.data.shape[0]
        ok &= row(f"gprMax {name[:24]} Ez", "ImpDAR 1.2.1 load_gprMax", ez[:, cut:], gm.data.T,
                  f"(ImpDAR cut the first {cut} samples)")
        rg = read_radargram(out)
        with h5py.File(out, "r") as f:
            ref = np.asarray(f[f"rxs/rx1/{rg.header['component']}"]).T
            dt = float(f.attrs["dt"]) * 1e9
        ok &= row(f"gprMax {name[:24]} {rg.header['component']}", "h5py 3 direct", rg.samples, ref,
                  f"dt {rg.dt_ns:g} vs {dt:g} ns")
    print("all identical" if ok else "DIFFERENCES FOUND")
    return 0 if ok else 1


if __name__ == "__main__":
    here = Path(__file__).resolve().parents[1]
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else here.parent / "shared" / "data" / "real"))
