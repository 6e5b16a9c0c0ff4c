"""YAML configs: the shipped ones load; bad ones fail with the key's path in one line."""

from __future__ import annotations

import pytest
import yaml
from tcaff_gtsam.eval.config import (
    CONFIG_DIR,
    MethodsConfig,
    dump_study,
    load_methods,
    load_scenario,
    load_study,
)

from tcaff_gtsam.errors import ConfigError

SCENARIOS = sorted(p.stem for p in (CONFIG_DIR / "scenarios").glob("*.yaml"))


def test_every_scenario_of_the_paper_ships():
    assert set(SCENARIOS) >= {"ambiguous_grid", "four_robots", "indoor_return", "mot",
                              "opposite_directions", "same_direction"}


@pytest.mark.parametrize("name", SCENARIOS)
def test_shipped_scenarios_load(name):
    cfg = load_scenario(name)
    assert cfg.name == name
    assert cfg.n_robots == (4 if name in ("four_robots", "mot") else 2)


@pytest.mark.parametrize("name", ["default", "tcaff_only"])
def test_shipped_method_sets_load(name):
    assert load_methods(name).methods


@pytest.mark.parametrize("name", ["demo", "paper"])
def test_shipped_studies_load_with_everything_inline(name):
    study = load_study(name)
    assert {s.name for s in study.scenarios} == set(SCENARIOS) - {"ambiguous_grid_opposite"}
    assert isinstance(study.methods, MethodsConfig)


def test_outdoor_scenarios_use_the_papers_outdoor_settings():
    for name in ("same_direction", "opposite_directions"):
        cfg = load_scenario(name)
        assert cfg.mapping.kappa == 15.0 and cfg.window == 5


def test_effective_config_loads_again(tmp_path):
    study = load_study("demo", {"seeds": [3, 4], "workers": 1})
    path = tmp_path / "config.yaml"
    path.write_text(dump_study(study))
    again = load_study(path)
    assert again == study
    assert again.seeds == [3, 4]


def _write(tmp_path, data) -> str:
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return str(path)


SCENARIO = {"name": "s", "duration": 10, "layout": {"kind": "indoor_return"}}


@pytest.mark.parametrize(("data", "expected"), [
    ({"scenarios": ["indoor_return"], "bogus": 1}, "bogus: Extra inputs are not permitted"),
    ({"scenarios": ["indoor_return"], "workers": 0},
     "workers: Input should be greater than or equal to 1 (got 0)"),
    ({"scenarios": ["indoor_return"], "seeds": "zero"}, "seeds: Input should be a valid list"),
    ({"scenarios": []}, "scenarios: List should have at least 1 item"),
    ({"scenarios": [{**SCENARIO, "layout": {"kind": "indoor_return", "room": -1}}]},
     "scenarios.0.layout.room: Input should be greater than 2 (got -1)"),
    ({"scenarios": [{**SCENARIO, "sensor": {"fov_deg": "wide"}}]},
     "scenarios.0.sensor.fov_deg: Input should be a valid number"),
    ({"scenarios": [{**SCENARIO, "sensor": {"range_min": 5, "range_max": 2}}]},
     "range_max (2.0) must exceed range_min (5.0)"),
    ({"scenarios": [{**SCENARIO, "layout": {"kind": "castle"}}]},
     "scenarios.0.layout: Input tag 'castle'"),
    ({"scenarios": [{**SCENARIO, "odometry": [{"heading_rw_deg": 0.1}]}]},
     "odometry: a list needs one entry per robot (2), got 1"),
    ({"scenarios": [{**SCENARIO, "layout": {"kind": "indoor_return", "leave_at": 90,
                                            "return_at": 80}}]},
     "return_at (80.0) must be after leave_at (90.0)"),
    ({"scenarios": ["indoor_return"], "methods": {"methods": ["tcaff", "magic"]}},
     "methods.methods.1: Input should be"),
    ({"scenarios": ["indoor_return"], "methods": {"clipper_k": [3, 3]}},
     "clipper_k must be distinct ints >= 2"),
    ({"scenarios": ["indoor_return"], "methods": {"clipper_k": [3, 4], "clipper_k_shown": 10}},
     "clipper_k_shown (10) must be one of clipper_k [3, 4]"),
    ({"scenarios": ["indoor_return", "indoor_return"]}, "scenario names must be distinct"),
    ({"scenarios": ["atlantis"]}, "no scenario config named 'atlantis'; shipped: "),
    ("scenarios: [\n", "not valid YAML"),
    ("- just\n- a list\n", "expected a mapping of keys, got list"),
])
def test_bad_configs_name_the_key(tmp_path, data, expected):
    with pytest.raises(ConfigError) as info:
        load_study(_write(tmp_path, data))
    message = str(info.value)
    assert expected in message
    assert "\n" not in message


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_study(tmp_path / "missing.yaml")


def test_configs_are_frozen():
    cfg = load_scenario("indoor_return")
    with pytest.raises(Exception, match="frozen"):
        cfg.duration = 5.0
