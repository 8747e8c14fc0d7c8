"""Stage 7 (optional): a pipe's size from a segmentation of the section where its hyperbola does not measure it.

With the antenna above the ground, a cylinder's top arc looks like a point's to within a few hundredths of
a period (validation.hyperbola_signatures): the curve places the top but says little of the radius, so
the chain reports the middle of what the curve allows and marks it unmeasured (`reported_radius`). A
segmentation of the migrated section — MigrationNet's pipe mask — sees the reflection's extent in depth
(a large metal pipe's bright, long top; a PVC pipe's top and bottom), which the curve does not use.
Where one of its blobs has its top at the detection's top, its half-height is taken for the radius and
the centre is put that far below the top. The top, the x and the kind stay the chain's.
Measured (validation/REPORT.md, velocity given): FDTD dev half radius within 30 % 9 -> 14 of 39 pipes,
centres within 3 cm 27 -> 26; test half (run once) radius 7 -> 10 of 36 but centres within 3 cm 24 -> 19 and
false pipes 0.55 -> 0.70 a scene: a blob's half-height is as often the wavelet's as the pipe's (a 1 cm bar
reads 2-3 cm, a 6 cm pipe at 413 MHz 13 cm). So `interpretation.radius_from` is "fit" by default.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from gprbot.gpr.bscan import Detection
from gprbot.gpr.chain.classify import ClassifiedDetection

SAME_X_M = 0.03  # a blob's centre this near the detection's x ...
SAME_TOP_M = 0.02  # ... and its top this near the detection's top describe the same pipe
# The blobs' half-heights against the true radii of the 22 FDTD dev-half pipes they matched: median |log ratio|
# 0.198, a normal spread's 0.67 sigma, so sigma about 0.3 (the tails are heavier: rms 0.49, one blob 2.2x).
BLOB_RADIUS_REL_SIGMA = 0.3


def blob_for(d: ClassifiedDetection, blobs: Sequence[Detection]) -> Detection | None:
    """The blob whose top lies at the detection's top (the nearest, if several), or None."""
    near = [b for b in blobs
            if abs(b.x_m - d.x_m) <= SAME_X_M and abs((b.depth_m - b.radius_m) - d.fit.top_m) <= SAME_TOP_M]
    return min(near, key=lambda b: abs(b.x_m - d.x_m) + abs(b.depth_m - b.radius_m - d.fit.top_m), default=None)


def sized(detections: Sequence[ClassifiedDetection], blobs: Sequence[Detection]) -> tuple[ClassifiedDetection, ...]:
    """The detections, each pipe whose fit does not measure its radius given its blob's, where it has one."""
    out = []
    for d in detections:
        blob = blob_for(d, blobs) if d.kind == "pipe" and d.radius_source == "none" else None
        if blob is None or blob.radius_m <= 0.0:
            out.append(d)
            continue
        r = blob.radius_m
        out.append(replace(d, depth_m=d.fit.top_m + r, radius_m=r, radius_sigma_m=BLOB_RADIUS_REL_SIGMA * r,
                           radius_source="migrationnet"))
    return tuple(out)
