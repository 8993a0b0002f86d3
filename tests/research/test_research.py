"""The research code: the sweep's settings and options, the first-attempt rates of a dataset,
the re-exploration experiment (a tiny run end to end; its tables in ``test_explore.py``),
and the entry points in ``scripts/`` that run them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from care_maps.research.dataset_stats import first_attempt_rates
from care_maps.research.sweep import SWEEP_KNOBS, SweepConfig, settings_of, sweep_settings

ROOT = Path(__file__).resolve().parents[2]


def test_one_at_a_time_varies_each_knob_around_the_centre() -> None:
    config = SweepConfig(bias_rate=(0.3, 0.0, 0.1), base_noise=(0.6, 0.3))
    settings = sweep_settings(config)
    centre = settings[0]
    assert centre == {
        "bias_rate": 0.3,
        "bias_noise_scale": 1.0,
        "view_bias_rate": 0.5,
        "base_noise": 0.6,
    }
    for s in settings[1:]:
        assert sum(s[k] != centre[k] for k in SWEEP_KNOBS) == 1
    assert len(settings) == 1 + 2 + 1 + 1 + 1


def test_grid_takes_every_combination() -> None:
    settings = sweep_settings(SweepConfig(design="grid"))
    assert len(settings) == 2**4
    assert len({tuple(s.values()) for s in settings}) == 2**4


def test_settings_of_parses_knobs_and_refuses_others() -> None:
    assert settings_of(["bias_rate=0.1,0,0.3"]) == {"bias_rate": (0.1, 0.0, 0.3)}
    with pytest.raises(ValueError, match="sweep knob"):
        settings_of(["noise=1"])


def test_first_attempt_rates_keep_no_replan_and_put_the_grid_last() -> None:
    rows = [
        {"strategy": "no_replan", "map": "grid", "protocol": "class", "rate": 54.444},
        {"strategy": "no_replan", "map": "instances", "protocol": "instance", "rate": 12.091},
        {"strategy": "oracle", "map": "instances", "protocol": "instance", "rate": 90.0},
        {"strategy": "no_replan", "map": "instances", "protocol": "class", "rate": 20.0},
    ]
    rates = first_attempt_rates(rows)
    assert list(rates.items()) == [
        ("instances/class", 20.0),
        ("instances/instance", 12.09),
        ("grid", 54.44),
    ]


@pytest.mark.parametrize("name", ["sweep", "reproduce", "perception_breakdown", "explore"])
def test_scripts_and_modules_share_one_command_line(name: str) -> None:
    """``scripts/<name>.py`` is an entry point of ``care_maps.research.<name>``: both print one help."""
    script = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / f"{name}.py"), "--help"],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )  # fmt: skip
    module = subprocess.run(
        [sys.executable, "-m", f"care_maps.research.{name}", "--help"],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )  # fmt: skip
    # past the usage lines, which name the program as it was started
    assert script.stdout.split("\n\n", 1)[1] == module.stdout.split("\n\n", 1)[1]


@pytest.mark.slow
def test_the_explore_experiment_runs_end_to_end_at_a_tiny_size(tmp_path: Path) -> None:
    """One room at 48x36 with two new views: every condition is made, fused and compared."""
    from care_maps.research.explore import Condition, ExperimentConfig, run_experiment

    config = ExperimentConfig(scenes=1, views=2, width=48, height=36, rooms=1)
    report = run_experiment(tmp_path, config)
    assert "## first attempt" in report
    assert "## two attempts, max confidence" in report
    assert "| explore vs random |" in report
    assert "too few scenes for this family" in report  # one scene cannot reject
    assert "run time:" in report
    stores = tmp_path / "stores" / "scene_000"
    for condition in Condition:
        name = condition if condition == Condition.BEFORE else f"{condition}-2"
        assert (stores / name / "cells.parquet").is_file(), name


def test_the_sweep_has_enough_scenes_for_its_holm_family() -> None:
    """The default sweep compares 5 settings x (3 rules on the instance protocol + 3 on each
    of the 2 grid protocols) = 45 times; Holm over 45 can reject only if some p reaches
    0.05 / 45, and G scenes give no less than 2 / 2^G: 11 scenes (2/2048 <= 0.00111 <
    2/1024)."""
    from care_maps.research.reproduce import SWEEP_SCENES
    from care_maps.research.sweep import comparisons

    assert comparisons() == 5 * (3 + 2 * 3)
    assert 2 / 2**SWEEP_SCENES <= 0.05 / 45 < 2 / 2 ** (SWEEP_SCENES - 1)
