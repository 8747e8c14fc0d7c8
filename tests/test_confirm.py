"""MigrationNet's pipes confirmed against the chain: echoes and blobs on a rebar dropped, their blobs unmasked."""

from __future__ import annotations

import numpy as np

from gprbot.gpr.bscan import CrossSection, Detection
from gprbot.infer.confirm import confirm, without_blobs

PIPE = Detection(0.30, 0.12, 0.02, 0.95)
ECHO = Detection(0.31, 0.26, 0.03, 0.80)  # right under it, where its bottom and ringing arrive
ASIDE = Detection(0.60, 0.20, 0.02, 0.90)


def test_a_blob_under_a_pipe_with_no_chain_target_there_is_dropped_as_its_echo() -> None:
    result = confirm([PIPE, ECHO, ASIDE], chain_found=[PIPE], chain_rebars=[])
    assert result.kept == (PIPE, ASIDE)
    ((dropped, why),) = result.dropped
    assert dropped is ECHO and "echoes" in why


def test_a_second_pipe_under_the_first_is_kept_where_the_chain_found_it_too() -> None:
    chain_second = Detection(0.315, 0.25, 0.02, 0.7)
    result = confirm([PIPE, ECHO], chain_found=[PIPE, chain_second], chain_rebars=[])
    assert result.kept == (PIPE, ECHO) and not result.dropped


def test_a_lone_blob_the_chain_did_not_see_is_kept() -> None:
    # The rule is about echoes only: a pipe the chain missed (a weak or overlapped hyperbola) stays.
    assert confirm([ASIDE], chain_found=[], chain_rebars=[]).kept == (ASIDE,)


def test_a_blob_on_a_chain_rebar_is_reported_once_as_the_rebar() -> None:
    bar = Detection(0.61, 0.21, 0.006, 0.9)
    result = confirm([PIPE, ASIDE], chain_found=[PIPE, bar], chain_rebars=[bar])
    assert result.kept == (PIPE,) and result.dropped[0][0] is ASIDE and "rebar" in result.dropped[0][1]


def test_a_dropped_blob_leaves_the_mask_and_the_others_stay() -> None:
    x, z = np.arange(0.0, 0.8, 0.01), np.arange(0.0, 0.4, 0.005)
    mask = np.zeros((len(z), len(x)), dtype=bool)
    for d in (PIPE, ECHO):
        mask |= (x[None, :] - d.x_m) ** 2 + (z[:, None] - d.depth_m) ** 2 <= d.radius_m ** 2
    section = CrossSection(mask, x, z, np.zeros(mask.shape, np.float32), (PIPE, ECHO), 0.1, False)
    out = without_blobs(section, [ECHO])
    assert out.detections == (PIPE,)
    assert out.mask[np.argmin(np.abs(z - PIPE.depth_m)), np.argmin(np.abs(x - PIPE.x_m))]
    assert not out.mask[z > 0.2].any() and out.mask.sum() < mask.sum()
    assert section.mask.sum() == mask.sum()  # the input is not changed



def test_the_survey_pipeline_leaves_an_echo_out_of_the_registered_slice() -> None:
    """interpret_line with MigrationNet on an FDTD dev scene whose pipe's echo the network also marks."""
    from dataclasses import replace

    from gprbot.config import Config
    from gprbot.gpr.preprocess import preprocess
    from gprbot.infer.pipeline import interpret_line
    from validation.cases import fdtd_cases

    (case,) = [c for c in fdtd_cases() if c.name == "random_25"]
    bscan, gpr = case.load()
    base = Config()
    cfg = replace(base, gpr=gpr, interpretation=replace(base.interpretation, method="migrationnet"))
    result = interpret_line(0, preprocess(bscan, gpr), cfg, case.velocity or 0.0)
    (pipe,) = result.section.detections
    assert abs(pipe.depth_m - 0.100) <= 0.03
    assert not result.section.mask[result.section.z_m > 0.2].any()  # the echo's blob left the mask too
    assert len(result.slice.points) and float(result.slice.points[:, 2].min()) > -0.2
