"""GPR file formats: detect by content, read any into a `Radargram`, write DZT, DT1+HD, SEG-Y and SU.

Read: GSSI DZT, Sensors & Software DT1+HD (+ .GPS), MALÅ RD3/RD7+RAD, SEG-Y rev 0/1, Seismic Unix,
gprMax .out (HDF5, needs the [formats] extra). Write: DZT, DT1+HD, SEG-Y, SU.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.radargram import Radargram, sibling

__all__ = ["READ_FORMATS", "WRITE_FORMATS", "Radargram", "detect_format", "read_radargram", "write_radargram"]

READ_FORMATS = ("dzt", "dt1", "mala", "segy", "su", "gprmax")
WRITE_FORMATS = {".dzt": "dzt", ".dt1": "dt1", ".hd": "dt1", ".sgy": "segy", ".segy": "segy", ".su": "su"}
_BY_SUFFIX = {".dzt": "dzt", ".dt1": "dt1", ".rd3": "mala", ".rd7": "mala", ".sgy": "segy", ".segy": "segy",
              ".su": "su", ".out": "gprmax"}
_HEAD = 3600 + 240 + 4 * 65536  # enough for a SEG-Y reel header or one SU trace of any length, plus a header


def _is_dzt(head: bytes) -> bool:
    """rh_tag 0xnnFF (0x00FF, 0xFnFF, SIR-4000's 0x07FF) or 0x0n00, a sample count and 8/16/32 bits."""
    if len(head) < 1024:
        return False
    tag, _, nsamp, bits = np.frombuffer(head, "<u2", count=4)
    low, high = int(tag) & 0xFF, int(tag) >> 8
    tag_ok = low == 0xFF or (low == 0 and 1 <= high <= 0x0F)
    return tag_ok and int(nsamp) > 0 and int(bits) in (8, 16, 32)


def _is_dt1(head: bytes, size: int, has_hd: bool) -> bool:
    """A first 128-byte trace header whose points and bytes per point divide the file size (or an .HD beside)."""
    if len(head) < 128:
        return False
    words = np.frombuffer(head, "<f4", count=8)
    points, bpp = float(words[2]), float(words[5])
    if not (np.isfinite(points) and points == int(points) and 0 < points <= 65536 and bpp in (2.0, 4.0)):
        return False
    return has_hd or size % (128 + int(bpp) * int(points)) == 0


def detect_format(path: str | Path) -> str:
    """The format of a GPR file from its content (and its header sidecar), one of READ_FORMATS."""
    from gprbot.gpr.formats.mala import looks_like_rad
    from gprbot.gpr.formats.radargram import read_text
    from gprbot.gpr.formats.segy import segy_layout
    from gprbot.gpr.formats.su import su_layout

    p = Path(path)
    try:
        size = p.stat().st_size
        with p.open("rb") as f:
            head = f.read(_HEAD)
    except OSError as exc:
        raise DataFormatError(f"cannot read {p}: {exc.strerror or exc}; check the path") from exc
    suffix = p.suffix.lower()
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return "gprmax"
    if suffix == ".hd" or (head[:4] == b"1234" and sibling(p, (".dt1",))):
        return "dt1"
    if suffix == ".rad" or head[:8].upper() == b"SAMPLES:":
        return "mala"
    layout = segy_layout(head)
    if layout is not None and head[:1] in (b"C", b"\xc3"):
        return "segy"
    if _is_dzt(head):
        return "dzt"
    if _is_dt1(head, size, sibling(p, (".hd",)) is not None):
        return "dt1"
    rad = sibling(p, (".rad",))
    if rad is not None and looks_like_rad(read_text(rad, "MALÅ header")):
        return "mala"
    if su_layout(head, size) is not None:
        return "su"
    if layout is not None:
        return "segy"
    if suffix in _BY_SUFFIX:  # content unclear (a cut file?): the suffix names the reader, which says what is wrong
        return _BY_SUFFIX[suffix]
    raise DataFormatError(
        f"{p}: not a GPR file this reader knows (DZT, DT1+HD, RD3/RD7+RAD, SEG-Y, SU, gprMax .out); "
        "check the file, or that its header sidecar (.HD, .rad) sits beside it"
    )


def read_radargram(
    path: str | Path, fmt: str | None = None, *, channel: int = 0, allow_partial: bool = False
) -> Radargram:
    """Read any supported GPR file (format detected unless `fmt` is given); DataFormatError if unsound."""
    p = Path(path)
    kind = fmt or detect_format(p)
    if channel != 0 and kind != "dzt":
        raise DataFormatError(f"{p}: a {kind} file has one channel; --channel applies to DZT files only")
    if kind == "dzt":
        from gprbot.gpr.formats.dzt_io import read_dzt_radargram

        return read_dzt_radargram(p, channel=channel, allow_partial=allow_partial)
    if kind == "dt1":
        from gprbot.gpr.formats.dt1 import read_dt1

        return read_dt1(p, allow_partial=allow_partial)
    if kind == "mala":
        from gprbot.gpr.formats.mala import read_mala

        return read_mala(p, allow_partial=allow_partial)
    if kind == "segy":
        from gprbot.gpr.formats.segy import read_segy

        return read_segy(p, allow_partial=allow_partial)
    if kind == "su":
        from gprbot.gpr.formats.su import read_su

        return read_su(p, allow_partial=allow_partial)
    if kind == "gprmax":
        from gprbot.gpr.formats.gprmax import read_gprmax

        return read_gprmax(p)
    raise DataFormatError(f"unknown format {kind!r}; choose one of {', '.join(READ_FORMATS)}")


def write_radargram(path: str | Path, rg: Radargram, fmt: str | None = None) -> tuple[list[Path], list[str]]:
    """Write `rg` as `fmt` (default: from the suffix); returns the files written and what was not kept."""
    p = Path(path)
    kind = fmt or WRITE_FORMATS.get(p.suffix.lower())
    if kind == "dzt":
        from gprbot.gpr.formats.dzt_io import write_dzt_radargram

        return write_dzt_radargram(p, rg)
    if kind == "dt1":
        from gprbot.gpr.formats.dt1 import write_dt1

        return write_dt1(p, rg)
    if kind == "segy":
        from gprbot.gpr.formats.segy import write_segy

        return write_segy(p, rg)
    if kind == "su":
        from gprbot.gpr.formats.su import write_su

        return write_su(p, rg)
    raise DataFormatError(
        f"cannot write {p.name}: name the output .DZT, .DT1 (with .HD), .sgy/.segy or .su "
        "(MALÅ and gprMax files are read only)"
    )
