"""The random scene generator: valid, deterministic, within the drawn ranges, every pipe crossing the lines."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.sim.scene import parse_scene
from training.random_scenes import (
    CASES,
    _clear,
    gpr_config,
    line_antenna_xy,
    random_scene,
    recorded_positions,
    scene_for_seed,
    scene_to_dict,
    split_seeds,
)

SEEDS = [*range(0, 90), *split_seeds("test")[:30]]


def test_splits_have_the_papers_sizes_and_are_disjoint() -> None:
    train, val, test = (set(split_seeds(s)) for s in ("train", "val", "test"))
    assert (len(train), len(val), len(test)) == (1378, 100, 150)
    assert not (train & val) and not (train & test) and not (val & test)


def test_a_seed_gives_the_same_scene_every_time() -> None:
    assert scene_for_seed(17) == scene_for_seed(17)
    assert scene_for_seed(17)[0] != scene_for_seed(18)[0]


@pytest.mark.parametrize("seed", SEEDS)
def test_scenes_pass_the_scene_files_validation(seed: int) -> None:
    scene, _ = scene_for_seed(seed)
    assert parse_scene(scene_to_dict(scene), f"seed {seed}") == scene


def test_every_segment_crosses_the_lines_at_45_degrees_or_more() -> None:
    for seed in SEEDS:
        scene, _ = scene_for_seed(seed)
        for pipe in scene.pipes:
            for a, b in pipe.segments():
                dx, dy = abs(b[0] - a[0]), abs(b[1] - a[1])
                assert np.degrees(np.arctan2(dy, dx)) >= 45.0, (seed, pipe.name)


def test_drawn_values_stay_in_their_ranges() -> None:
    for seed in SEEDS:
        scene, spec = scene_for_seed(seed)
        assert 4.0 <= spec.eps_r <= 12.0 and spec.eps_r == scene.slab.eps_r
        assert 400.0 <= spec.centre_frequency_mhz <= 2600.0
        assert 0.05 <= spec.spacing_m <= 0.25 and 5 <= spec.lines <= 12
        assert 1 <= len({p.name.split("_")[0] for p in scene.pipes}) <= 4
        for pipe in scene.pipes:
            assert 0.01 <= pipe.radius_m <= 0.1
            cover = -pipe.points[:, 2] - pipe.radius_m
            assert np.all((cover >= 0.05 - 1e-4) & (cover <= 0.4 + 1e-4))
            if scene.rebar is not None:
                assert np.all(cover > scene.rebar.cover_m + 2 * scene.rebar.diameter_m)


def test_cases_cycle_and_each_has_its_shape() -> None:
    for seed in range(len(CASES) * 4):
        scene, spec = scene_for_seed(seed)
        case = CASES[seed % len(CASES)]
        assert scene.name == f"random_{case}"
        if case == "bend":
            assert len(scene.pipes[0].points) == 3
        if case == "tee":
            main, branch = scene.pipes[0], scene.pipes[1]
            junction = branch.points[0]
            a, b = main.points
            t = np.dot(junction - a, b - a) / np.dot(b - a, b - a)
            assert np.linalg.norm(a + t * (b - a) - junction) < 1e-3  # the branch starts on the main's axis
        if case == "multi":
            assert 2 <= len(scene.pipes) <= 4
        if case == "missing":
            assert spec.missing_lines and all(0 < i < spec.lines - 1 for i in spec.missing_lines)
            assert set(spec.kept_lines()).isdisjoint(spec.missing_lines)
        else:
            assert spec.missing_lines == ()


def test_separate_pipes_keep_their_clearance() -> None:
    for seed in SEEDS:
        scene, _ = scene_for_seed(seed)
        pipes = [p for p in scene.pipes if not p.name.endswith("_branch")]
        for i, a in enumerate(pipes):
            for b in pipes[i + 1:]:
                assert _clear(a, b), (seed, a.name, b.name)


def test_unknown_case_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown case"):
        random_scene(np.random.default_rng(0), case="spiral")


def test_survey_geometry_and_time_window() -> None:
    scene, spec = scene_for_seed(3)
    xy = line_antenna_xy(spec, 2)
    assert np.allclose(xy[:, 1], spec.start_xy[1] + 2 * spec.spacing_m)
    assert xy[0, 0] == pytest.approx(spec.start_xy[0]) and xy[-1, 0] == pytest.approx(spec.length_m, abs=0.003)
    noisy = recorded_positions(xy, spec, np.random.default_rng(0))
    assert noisy.shape == (len(xy), 3)
    assert np.std(noisy[:, :2] - xy) == pytest.approx(spec.pose_noise_m, rel=0.2)
    gpr = gpr_config(spec, scene)
    bottom_ns = gpr.pre_trigger_ns + 2 * scene.slab.thickness_m / velocity_from_eps(scene.slab.eps_r)
    assert gpr.time_window_ns >= bottom_ns and gpr.centre_frequency_mhz == spec.centre_frequency_mhz
