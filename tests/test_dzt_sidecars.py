"""DZG (NMEA + $GSSIS), DZX (XML) and MRK sidecars: parsed when sound, ignored with a note when
broken (readgssi crashes on several of these), and safe against hostile XML."""

from __future__ import annotations

import contextlib
from functools import reduce
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gprbot.errors import DataFormatError
from gprbot.gpr.dzt import read_dzt
from gprbot.gpr.dzt_sidecars import parse_dzg, parse_dzx, parse_mrk, safe_xml

from .test_dzt_variants import sir4000_bytes


def nmea(body: str) -> str:
    """An NMEA sentence with its checksum."""
    return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"


def dzg_text(fixes: list[tuple[int, float, float, float]], rmc: bool = True) -> str:
    """A SIR-4000-style DZG: per fix a $GSSIS line, then GGA (and RMC) sentences."""
    lines = []
    for k, (scan, lat, lon, alt) in enumerate(fixes):
        t = f"1422{k:02d}.00"
        la = f"{int(abs(lat)):02d}{(abs(lat) % 1) * 60:010.7f},{'N' if lat >= 0 else 'S'}"
        lo = f"{int(abs(lon)):03d}{(abs(lon) % 1) * 60:010.7f},{'E' if lon >= 0 else 'W'}"
        lines.append(f"$GSSIS,{scan},{1571235309 + k}")
        lines.append(nmea(f"GPGGA,{t},{la},{lo},4,12,0.90,{alt:.3f},M,-26.879,M,1.0,0000"))
        if rmc:
            lines.append(nmea(f"GPRMC,{t},A,{la},{lo},0.5,90.0,161019,,,D"))
    return "\r\n".join(lines) + "\r\n"


FIXES = [(0, 44.8989, -68.6561, 31.2), (40, 44.8990, -68.6560, 31.4), (80, 44.8991, -68.6559, 31.8)]


def test_dzg_fixes_interpolate_per_trace() -> None:
    track, notes = parse_dzg(dzg_text(FIXES).encode())
    assert notes == ()
    np.testing.assert_array_equal(track.scans, [0, 40, 80])
    lat, lon, elev = track.per_trace(120)
    assert lat[0] == pytest.approx(44.8989, abs=1e-7) and lon[80] == pytest.approx(-68.6559, abs=1e-7)
    assert lat[20] == pytest.approx(44.89895, abs=1e-7) and elev[60] == pytest.approx(31.6, abs=1e-6)
    assert np.isnan(lat[81:]).all()  # no extrapolation beyond the last fix


def test_sir4000_with_dzg_and_dzx_sidecars(tmp_path: Path) -> None:
    path = tmp_path / "FILE____012.DZT"
    path.write_bytes(sir4000_bytes())
    (tmp_path / "FILE____012.DZG").write_text(dzg_text(FIXES))
    (tmp_path / "FILE____012.DZX").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<DZX xmlns="www.geophysical.com/DZX/1.02">'
        "<GlobalProperties><horizontalUnit>ft</horizontalUnit><dielectric>6.5</dielectric>"
        "<unitsPerScan>0.082</unitsPerScan></GlobalProperties><File><scanRange>0,119</scanRange><Profile>"
        "<WayPt><scan>0</scan><mark>Distance</mark><distance>0</distance></WayPt>"
        "<WayPt><scan>100</scan><mark>Distance</mark><distance>8.2</distance></WayPt>"
        "<WayPt><scan>60</scan><mark>User</mark><name>Mark1</name></WayPt>"
        "</Profile></File></DZX>"
    )
    dzt = read_dzt(path)
    assert dzt.warnings == ()
    assert dzt.gps is not None and len(dzt.gps.scans) == 3
    positions = dzt.trace_positions()
    assert positions is not None and positions[0][40] == pytest.approx(44.8990, abs=1e-7)
    assert dzt.dzx is not None and dzt.dzx.user_marks() == (60,) and dzt.dzx.scan_range == (0, 119)
    distance = dzt.trace_distance_m()
    assert distance is not None and distance[100] == pytest.approx(8.2 * 0.3048)
    assert distance[119] == pytest.approx(119 * 0.082 * 0.3048)  # extended at the last segment's rate
    assert dzt.marks == (0, 50, 100)  # the trace headers' marks win over the DZX user mark


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ("", "no GPS fix"),
        ("$GSSIS,0,1\r\n$GSSIS,1,2\r\n", "no GPS fix"),  # GSSIS lines only: readgssi's td is never set
        ("$GPGGA,142834.00,,,,,0,00,,,M,,M,,*66\r\n", "no GPS fix"),  # no fix, no GSSIS
        ("$GSSIS,0,1\r\n$GPGGA,142834.00,,,,,0,00,,,M,,M,,*66\r\n", "no GPS fix"),  # empty fix fields
        ("\x00\xff\xfe garbage \x89PNG\r\n", "no GPS fix"),
        ("$GSSIS,0,1\r\n" + nmea("GPGGA,1,9999.0,N,06839.3,W,1,5,1,2,M,,M,,"), "no GPS fix"),  # 99° 99'
    ],
)
def test_broken_dzg_is_ignored_with_a_note(tmp_path: Path, text: str, expect: str) -> None:
    with pytest.raises(DataFormatError, match=expect):
        parse_dzg(text.encode("latin-1"))
    path = tmp_path / "FILE____012.DZT"
    path.write_bytes(sir4000_bytes())
    (tmp_path / "FILE____012.DZG").write_bytes(text.encode("latin-1"))
    dzt = read_dzt(path)
    assert dzt.gps is None and dzt.header.traces == 120
    assert [w for w in dzt.warnings if w.startswith("FILE____012.DZG ignored: no GPS fix")]


def test_dzg_bad_checksums_and_paused_scans_are_noted() -> None:
    text = dzg_text(FIXES).replace("$GPGGA,142201", "$GPGGA,142209")  # corrupt one GGA: checksum fails
    reordered = "$GSSIS,200,9\r\n" + nmea("GPGGA,142900.00,4453.9,N,06839.3,W,1,5,1,2,M,,M,,") + "\r\n" + text
    track, notes = parse_dzg(reordered.encode())
    assert list(track.scans) == [0, 40, 80, 200]
    assert any("skipped" in n for n in notes) and any("backwards" in n for n in notes)
    # the RMC of scan 40 stands in for its lost GGA: position known, elevation not
    assert track.latitude[1] == pytest.approx(44.8990, abs=1e-7) and np.isnan(track.elevation_m[1])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from([*dzg_text(FIXES).splitlines(), "$GSSIS,", "$GSSIS,-4,1", "$GPGGA,,,,", "$,*ZZ"])))
def test_any_mix_of_dzg_lines_parses_or_raises_data_format_error(lines: list[str]) -> None:
    with contextlib.suppress(DataFormatError):
        track, _ = parse_dzg("\n".join(lines).encode())
        assert (np.diff(track.scans) > 0).all()
        assert np.all(np.abs(track.latitude) <= 90) and np.all(np.abs(track.longitude) <= 180)


# --- DZX ------------------------------------------------------------------------------------------


def test_dzx_refuses_dtds_and_entity_bombs() -> None:
    bomb = (
        b'<?xml version="1.0"?><!DOCTYPE DZX [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">]>'
        b"<DZX>&b;</DZX>"
    )
    with pytest.raises(DataFormatError, match="DTD or entity"):
        parse_dzx(bomb)
    external = b'<?xml version="1.0"?><!DOCTYPE DZX SYSTEM "file:///etc/passwd"><DZX/>'
    with pytest.raises(DataFormatError, match="DTD or entity"):
        parse_dzx(external)
    with pytest.raises(DataFormatError, match="nested deeper"):
        safe_xml(b"<a>" * 100 + b"</a>" * 100, "deep", 10_000)
    with pytest.raises(DataFormatError, match="more than the 10 bytes"):
        safe_xml(b"<DZX></DZX>", "big", 10)


@pytest.mark.parametrize(
    "raw",
    [b"", b"<DZX>", b"not xml at all", b"<other/>", b"\xff\xfe<\x00D\x00", b"<DZX><File><Profile><WayPt><scan>x"],
)
def test_broken_dzx_is_ignored_with_a_note(tmp_path: Path, raw: bytes) -> None:
    path = tmp_path / "LINE.DZT"
    path.write_bytes(sir4000_bytes())
    (tmp_path / "LINE.DZX").write_bytes(raw)
    dzt = read_dzt(path)
    assert dzt.dzx is None and [w for w in dzt.warnings if w.startswith("LINE.DZX ignored")]


def test_dzx_waypoints_with_odd_values_are_skipped_not_fatal() -> None:
    info = parse_dzx(
        b"<DZX><GlobalProperties><dielectric>-3</dielectric><horizontalUnit>furlong</horizontalUnit>"
        b"</GlobalProperties><File><Profile>"
        b"<WayPt><scan>-1</scan><mark>User</mark></WayPt><WayPt><scan>5</scan><distance>nan</distance></WayPt>"
        b"<WayPt><scan>9</scan><mark>Distance</mark><distance>2</distance></WayPt>"
        b"<WayPt><scan>19</scan><mark>Distance</mark><distance>1</distance></WayPt>"
        b"</Profile></File><TargetGroup><TargetWayPt><scanSampChanProp>12,40,0</scanSampChanProp></TargetWayPt>"
        b"</TargetGroup></DZX>"
    )
    assert info.dielectric is None and info.unit_m is None and info.target_scans == (12,)
    assert [w.scan for w in info.waypoints] == [5, 9, 19]
    distance, notes = info.distance_m(30)
    assert distance is None and "unknown" in notes[0]


def test_mrk_parsing() -> None:
    assert parse_mrk(b" 194  1  1  200\r\n 358  2  1  200\r\n\r\n") == (193, 357)
    for bad in (b"", b"abc 1 2\n", b"0 1 1\n"):
        with pytest.raises(DataFormatError):
            parse_mrk(bad)
