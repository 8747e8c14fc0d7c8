"""GSSI antenna names → centre frequency (MHz), as DZT headers spell them.

A DZT header's rh_antname (14 bytes per channel) holds what the control unit was told: a GSSI
model number ("5103", "3101A", "62000-003", "D50800"), a frequency in text ("400MHz", "1.5 GHz",
"400D") or a product name ("SS MINI #454"). The table is GSSI's antenna catalogue as the public
readers know it (readgssi's ANT map, RGPR's getAntFreqGSSI); adjustable multi-frequency units
(3200, 3200MLF) and custom names have no single frequency: the caller asks for --frequency.
"""

from __future__ import annotations

import re

FREQUENCY_MIN_MHZ = 10.0  # the lowest GPR antennas (glacier and rock sounding) are 10-25 MHz
FREQUENCY_MAX_MHZ = 10_000.0  # the highest GPR antennas (concrete, 2.6-6 GHz) stay below 10 GHz

# GSSI model numbers → centre frequency (MHz).
GSSI_ANTENNAS: dict[str, float] = {
    "3207": 100, "3207AP": 100, "5106": 200, "5106A": 200, "50270": 270, "50270S": 270,
    "50300": 300, "D50300": 300, "350HS": 350, "D400HS": 350, "5103": 400, "5103A": 400,
    "50400": 400, "50400S": 400, "3102": 500, "D50800": 800, "3101": 900, "3101A": 900,
    "5100": 1500, "51600": 1600, "51600S": 1600, "4105NR": 2000, "42000S": 2000, "62000": 2000,
    "62300": 2300, "62300XT": 2300, "52600": 2600, "52600S": 2600,
}  # fmt: skip
# Product names that the units write instead of a model number (checked in this order).
GSSI_PRODUCTS: tuple[tuple[str, float], ...] = (
    ("SSMINIXT", 2700.0),  # StructureScan Mini XT (readgssi fixes rh_system 14 to 2700 MHz)
    ("SSMINIHR", 2600.0),
    ("SSMINI", 1600.0),  # StructureScan Mini: its 1.6 GHz palm antenna
    ("1.5/1.6GHZ", 1500.0),
    ("300/800D", 300.0),  # a dual-frequency antenna; channel 0 is the 300 MHz one
)

_TEXT_FREQUENCY = re.compile(r"(\d+(?:\.\d+)?)\s*([MG])\s*HZ", re.IGNORECASE)
_MODEL_TOKEN = re.compile(r"(?<![0-9A-Z])(D?\d{3,5}[A-Z]{0,2})", re.IGNORECASE)
_DIGITAL_SERIES = re.compile(r"^\s*(\d{2,4})\s*(?:D|HS)\b", re.IGNORECASE)  # "400D", "350HS"


def antenna_frequency_mhz(antenna: str) -> float | None:
    """Centre frequency (MHz) of a GSSI antenna from its header name, or None when it is not known.

    Frequencies in text win ("400MHz", "1.5 GHz"), then product names, then catalogue model numbers
    (as whole tokens: "62000-003" is a 62000), then the digital series' "nnnD". A result outside
    10 MHz-10 GHz (e.g. "0MHz") is not a GPR antenna and gives None, so callers ask for --frequency.
    """
    squeezed = antenna.upper().replace(" ", "")
    for product, mhz in GSSI_PRODUCTS:
        if product in squeezed:
            return mhz
    text = _TEXT_FREQUENCY.search(antenna)
    if text:
        return _plausible(float(text.group(1)) * (1000.0 if text.group(2).upper() == "G" else 1.0))
    for token in _MODEL_TOKEN.findall(antenna.upper()):
        for candidate in (token, token.rstrip("ABCDEFGHIJKLMNOPQRSTUVWXYZ"), token.lstrip("D")):
            if candidate in GSSI_ANTENNAS:
                return GSSI_ANTENNAS[candidate]
    series = _DIGITAL_SERIES.match(antenna)
    if series:
        return _plausible(float(series.group(1)))
    return None


def check_frequency_mhz(mhz: float) -> str | None:
    """None when `mhz` is a plausible GPR centre frequency, else a message naming the bounds."""
    if FREQUENCY_MIN_MHZ <= mhz <= FREQUENCY_MAX_MHZ:  # false for NaN
        return None
    return (
        f"centre frequency {mhz:g} MHz is outside what GPR antennas use "
        f"({FREQUENCY_MIN_MHZ:g} MHz to {FREQUENCY_MAX_MHZ / 1000:g} GHz)"
    )


def _plausible(mhz: float) -> float | None:
    return mhz if check_frequency_mhz(mhz) is None else None
