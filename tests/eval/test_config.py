"""YAML configs: the shipped ones load; bad ones fail with the key's path in one line."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
import yaml
from pydantic import ValidationError
from tcaff_gtsam.eval.config import (
    CONFIG_DIR,
    MethodsConfig,
    PedestriansConfig,
    ScenarioConfig,
    TrackerParams,
    dump_study,
    load_methods,
    load_scenario,
    load_study,
    load_sweep,
)
from tcaff_gtsam.eval.tracker import TrackerParams as TrackerParamsOfTheTracker
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.params import FrameAlignerParams, GraphParams, TCAFFParams

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


def test_a_studys_durations_cap_the_scenarios_they_name(tmp_path):
    """A cap shortens its scenario, never lengthens it, and leaves the others; a study cut to a
    few scenarios (`tcaff study demo -s mot`) keeps the caps of those it runs."""
    study = load_study(_write(tmp_path, {
        "scenarios": ["indoor_return", "opposite_directions", "same_direction"],
        "durations": {"indoor_return": 100, "opposite_directions": 500}}))
    assert [s.duration for s in study.scenarios] == [
        100, load_scenario("opposite_directions").duration,
        load_scenario("same_direction").duration]
    demo = load_study("demo")
    assert demo.durations and all(
        s.duration == min(load_scenario(s.name).duration, demo.durations.get(s.name, np.inf))
        for s in demo.scenarios)
    only_mot = load_study("demo", {"scenarios": ["mot", "indoor_return"]})
    assert [s.duration for s in only_mot.scenarios] == [demo.durations["mot"],
                                                        load_scenario("indoor_return").duration]
    # the caps of the scenarios left out are dropped, so the effective config loads again
    assert only_mot.durations == {"mot": demo.durations["mot"]}
    path = tmp_path / "config.yaml"
    path.write_text(dump_study(only_mot))
    assert load_study(path) == only_mot


def test_a_sweeps_inline_study_with_a_durations_typo_is_refused(tmp_path):
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({"name": "s", "grid": {"methods.tcaff.tau": [4.0]}, "study": {
        "scenarios": ["indoor_return"], "durations": {"indoor_retrun": 60}}}))
    with pytest.raises(ConfigError, match=r"durations names \['indoor_retrun'\]"):
        load_sweep(path)


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
     "methods.methods: unknown methods ['magic']; registered: tcaff"),
    ({"scenarios": ["indoor_return"], "methods": {"clipper_k": [3, 3]}},
     "clipper_k must be distinct ints >= 2"),
    ({"scenarios": ["indoor_return"], "methods": {"clipper_k": [3, 4], "clipper_k_shown": 10}},
     "clipper_k_shown (10) must be one of clipper_k [3, 4]"),
    ({"scenarios": ["indoor_return", "indoor_return"]}, "scenario names must be distinct"),
    ({"scenarios": ["indoor_return"], "durations": {"indoor_retrun": 60}},
     "study.yaml: durations names ['indoor_retrun'], which are not among its scenarios "
     "['indoor_return']"),
    # pydantic would take true for 1 (a one-second run, one worker, seed 1)
    ({"scenarios": ["indoor_return"], "durations": {"indoor_return": True}},
     "durations.indoor_return: must be a number, not true/false (got True)"),
    ({"scenarios": [{**SCENARIO, "duration": True}]},
     "scenarios.0.duration: must be a number, not true/false (got True)"),
    ({"scenarios": ["indoor_return"], "seeds": [0, True]},
     "seeds.1: must be a number, not true/false (got True)"),
    ({"scenarios": [{**SCENARIO, "sensor": {"fov_deg": False}}]},
     "scenarios.0.sensor.fov_deg: must be a number, not true/false (got False)"),
    ({"scenarios": ["indoor_return"], "durations": {"indoor_return": 0}},
     "durations.indoor_return: Input should be greater than or equal to 1 (got 0)"),
    ({"scenarios": ["indoor_return"], "durations": {"indoor_return": float("nan")}},
     "durations.indoor_return: Input should be less than or equal to 7200 (got nan)"),
    ({"scenarios": ["indoor_return"], "durations": {"indoor_return": "short"}},
     "durations.indoor_return: Input should be a valid number"),
    ({"scenarios": ["atlantis"]}, "no scenario config named 'atlantis'; shipped: "),
    # values the core parameter objects refuse, with the key's path
    ({"scenarios": ["indoor_return"], "methods": {"aligner": {"n_solutions": 0}}},
     "methods.aligner.n_solutions: must be an int in [1, 1000] (MAX_SOLUTIONS) (got 0)"),
    ({"scenarios": ["indoor_return"], "methods": {"aligner": {"clipper": {"sigma": "a"}}}},
     "methods.aligner.clipper.sigma: must be a finite number >= 1e-9 and <= 1e9 metres "
     "(MIN_SIGMA, MAX_COORDINATE) (got 'a')"),
    ({"scenarios": ["indoor_return"], "methods": {"aligner": {"clipper": 3}}},
     "methods.aligner.clipper: must be a mapping of ClipperParams fields (got 3)"),
    ({"scenarios": ["indoor_return"], "methods": {"aligner": 5}},
     "methods.aligner: must be a mapping of FrameAlignerParams fields (got 5)"),
    ({"scenarios": ["indoor_return"], "methods": {"aligner": {"kappa": 5}}},
     "methods.aligner.kappa: is set per scenario/data set (mapping.kappa), not per method set "
     "(got 5)"),
    ({"scenarios": ["indoor_return"], "methods": {"tcaff": {"tau": None}}},
     "methods.tcaff.tau: must be a finite number >= -1e6 and <= 1e6 nats (MAX_NATS) "
     "(got None)"),
    ({"scenarios": ["indoor_return"], "methods": {"tcaff": {"Q": [[1, 0], [0, -1]]}}},
     "methods.tcaff.Q: must be a symmetric positive definite (d, d) matrix with entries "
     "of magnitude <= 1e18 (MAX_VARIANCE) (got [[1, 0], [0, -1]])"),
    ({"scenarios": ["indoor_return"], "methods": {"tcaff": {"bogus": 1}}},
     "methods.tcaff.bogus: Extra inputs are not permitted"),
    ({"scenarios": ["indoor_return"], "methods": {"graph": {"robust": "tukey"}}},
     "methods.graph.robust: must be 'huber', 'cauchy' or 'none' (got 'tukey')"),
    ({"scenarios": ["indoor_return"], "methods": {"graph": {"Q": [[1, 0], [0, 1]]}}},
     "methods.graph.Q: the alignment drift is set per scenario/data set (graph_drift)"),
    ({"scenarios": [{**SCENARIO, "mapping": {"nu": 0}}]},
     "scenarios.0.mapping.nu: must be an int >= 1 (got 0)"),
    ({"scenarios": [{**SCENARIO, "mapping": {"kappa": -1}}]},
     "scenarios.0.mapping.kappa: must be a number > 0 seconds (got -1)"),
    ({"scenarios": [{**SCENARIO, "window": 0}]},
     "scenarios.0.window: must be an int in [1, 1000] (MAX_WINDOW) (got 0)"),
    ({"scenarios": [{**SCENARIO, "pedestrians": {"tracker": {"gate": -1}}}]},
     "scenarios.0.pedestrians.tracker.gate: must be a finite number > 0 (got -1)"),
    ({"scenarios": [{**SCENARIO, "pedestrians": {"tracker": {"confirm_hits": "3"}}}]},
     "scenarios.0.pedestrians.tracker.confirm_hits: must be an int >= 1 (got '3')"),
    ({"scenarios": ["indoor_return"], "methods": {"thresholds": {"overlap_gap_steps": 0}}},
     "methods.thresholds.overlap_gap_steps: Input should be greater than or equal to 1"),
    ({"scenarios": ["indoor_return"], "methods": {"thresholds": {"judge_hold": -5}}},
     "methods.thresholds.judge_hold: Input should be greater than or equal to 0"),
    ({"scenarios": ["indoor_return"], "methods": {"thresholds": {"overlap_gap_steps": True}}},
     "methods.thresholds.overlap_gap_steps: must be a number, not true/false"),
    # a name becomes a folder: '.' and '..' would put the results beside or above --output
    ({"name": "..", "scenarios": ["indoor_return"]}, "name: String should match pattern"),
    ({"name": ".", "scenarios": ["indoor_return"]}, "name: String should match pattern"),
    ("scenarios: [\n", "not valid YAML"),
    ("- just\n- a list\n", "expected a mapping of keys, got list"),
    ("", "the config is empty; expected a mapping of keys"),
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


def test_window_is_set_per_run_not_per_method_set(tmp_path):
    path = tmp_path / "methods.yaml"
    path.write_text(yaml.safe_dump({"name": "w", "tcaff": {"window": 5}}))
    with pytest.raises(ConfigError) as info:
        load_methods(path)
    assert str(info.value) == (
        "methods.yaml: tcaff.window: the TCAFF window W is set per scenario/data set (window), "
        "not per method set (got 5)")
    with pytest.raises(ValidationError, match="window W is set per scenario"):
        MethodsConfig(tcaff=TCAFFParams(window=5))


def test_the_runs_window_applies_to_every_tcaff_preset():
    methods = MethodsConfig(tcaff={"tau": 7.0})
    default, reference = methods.tcaff_params(False, 5), methods.tcaff_params(True, 5)
    assert (default.window, default.tau) == (5, 7.0)
    assert (reference.window, reference.tau) == (5, TCAFFParams.reference().tau)
    assert methods.tcaff_params(False, None) == replace(TCAFFParams(), tau=7.0)
    assert methods.tcaff_params(True, None) == TCAFFParams.reference()


@pytest.mark.parametrize("name", ["default", "tcaff_only"])
def test_method_sets_take_the_parameter_objects_defaults(name):
    methods = load_methods(name)
    assert methods.aligner_params(15.0) == FrameAlignerParams(kappa=15.0)
    assert methods.tcaff_params(False, None) == TCAFFParams()
    assert methods.graph_params(None) == GraphParams()
    drift = methods.graph_params((1.0, 1.0))
    assert drift == GraphParams(Q=np.diag([1.0, 1.0, np.radians(1.0) ** 2]))
    assert methods.graph.robust == "huber"


def test_scenarios_take_the_mapper_and_tracker_defaults():
    scenario = ScenarioConfig(name="s", duration=10, layout={"kind": "indoor_return"})
    mapper = MapperParams()
    assert (scenario.mapping.nu, scenario.mapping.kappa) == (mapper.nu, mapper.kappa)
    assert mapper.kappa == FrameAlignerParams().kappa
    assert PedestriansConfig().tracker == TrackerParams()
    assert load_scenario("mot").pedestrians.tracker == TrackerParams()
    assert TrackerParamsOfTheTracker is TrackerParams


def test_effective_config_with_changed_parameters_loads_again(tmp_path):
    methods = {"aligner": {"covariance": "residual", "clipper": {"seed": 3},
                           "R_constant": np.diag([1.0, 2.0, 0.1]).tolist()},
               "tcaff": {"tau": 7.5, "Q": np.diag([0.02, 0.02, 1e-4]).tolist(),
                         "gate_box": [1, 1, 0.5]},
               "graph": {"robust": "cauchy"}}
    scenario = {**SCENARIO, "window": 4,
                "pedestrians": {"tracker": {"gate": 5.99, "max_coast": 2}}}
    study = load_study(_write(tmp_path, {"scenarios": [scenario], "methods": methods}))
    text = dump_study(study)
    dumped = yaml.safe_load(text)["methods"]
    assert "window" not in dumped["tcaff"] and "kappa" not in dumped["aligner"]
    assert "Q" not in dumped["graph"] and "dim" not in dumped["graph"]
    path = tmp_path / "config.yaml"
    path.write_text(text)
    again = load_study(path)
    assert again == study
    m = again.methods
    assert m.aligner_params(20.0).clipper.seed == 3 and m.aligner.covariance == "residual"
    assert m.tcaff_params(False, again.scenarios[0].window) == replace(
        TCAFFParams(tau=7.5, Q=np.diag([0.02, 0.02, 1e-4]), gate_box=(1, 1, 0.5)), window=4)
    assert again.scenarios[0].pedestrians.tracker == TrackerParams(gate=5.99, max_coast=2)


def test_the_scoring_thresholds_reach_the_metrics(tmp_path):
    """A method set's thresholds, its overlap gap and the judge's hold included, become the
    `metrics.Thresholds` every score uses; the defaults are the documented 5 steps and 40 s."""
    from tcaff_gtsam.eval.metrics import Thresholds
    from tcaff_gtsam.eval.results import thresholds_of

    assert thresholds_of(MethodsConfig()) == Thresholds()
    assert thresholds_of(load_methods("default")) == Thresholds()
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({"thresholds": {"translation": 0.5, "heading_deg": 2.0,
                                                   "overlap_gap_steps": 3,
                                                   "judge_hold": 12.5}}))
    assert thresholds_of(load_methods(str(path))) == Thresholds(0.5, np.radians(2.0), 3, 12.5)


@pytest.mark.parametrize(("change", "words"), [
    # names go into the bags' glob and into file names
    ({"robots": ["*", "acl_jackal2"]}, "robots must be distinct names"),
    ({"robots": ["a/b", "acl_jackal2"]}, "robots must be distinct names"),
    ({"robots": ["acl_jackal2", "acl_jackal2"]}, "robots must be distinct names"),
    ({"robots": ["..", "acl_jackal2"]}, "robots must be distinct names"),
    # pathlib's glob refuses absolute patterns with NotImplementedError
    ({"bags": "/etc/*{robot}*.bag"}, "bags must be a glob relative to --data"),
    ({"bags": "../*{robot}*.bag"}, "bags must be a glob relative to --data"),
    # every robot would map every bag
    ({"bags": "*.bag"}, "bags must be a glob relative to --data that holds {robot}"),
])
def test_a_kimera_test_refuses_names_and_globs_that_are_not_one_robots(tmp_path, change, words):
    from tcaff_gtsam.eval.config import load_kimera_multi

    base = yaml.safe_load(load_kimera_multi("same_direction").model_dump_json())
    path = tmp_path / "test.yaml"
    path.write_text(yaml.safe_dump({**base, **change}))
    with pytest.raises(ConfigError, match=re.escape(words)):
        load_kimera_multi(path)


@pytest.mark.parametrize(("part", "key", "value"), [
    ("sensor", "range_max", ".inf"),  # passed, then an OverflowError drawing false detections
    ("sensor", "centroid_noise", ".inf"),  # refused by the mapper, naming no key
    ("sensor", "centroid_noise_per_m", ".inf"),
    ("sensor", "centroid_noise", "1e308"),  # a DataError of the mapper's, as .inf
    ("camera", "mount_height", ".inf"),
    ("camera", "depth_max", ".inf"),
    ("pedestrians", "speed", "[0.5, .inf]"),
    ("pedestrians", "margin", ".inf"),
    ("pedestrians", "margin", "1e308"),  # an OverflowError placing the waypoints
    ("pedestrians", "match_distance", ".inf"),
    ("pedestrians.detector", "noise", ".inf"),
    ("mapping", "kappa", ".inf"),
    (None, "graph_drift", "[.inf, 1.0]"),
    ("layout", "lateral", "[2.0, .inf]"),
])
def test_a_scenario_refuses_numbers_past_what_it_simulates_naming_the_key(tmp_path, part, key,
                                                                          value):
    """Infinite (YAML .inf) or huge numbers where a field is bounded only below were taken,
    and the simulator failed on them, deep inside, or named no key."""
    data = {"name": "s", "duration": 10, "layout": {"kind": "same_direction"}}
    node = data
    for name in part.split(".") if part else []:
        node = node.setdefault(name, {})
    node[key] = yaml.safe_load(value)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    where = f"{part}.{key}" if part else key
    with pytest.raises(ConfigError, match=re.escape(f"s.yaml: {where}")):
        load_scenario(path)


@pytest.mark.parametrize(("loader", "key", "value"), [
    ("load_mrclam", "graph_drift", "[.inf, 1.0]"),  # taken, then refused deep in the graph
    ("load_mrclam", "kappa", ".inf"),
    ("load_mrclam", "vio", "{heading_rw_deg_per_sqrt_min: .nan}"),
    ("load_rgbd", "kappa", ".inf"),
    ("load_kimera_multi", "graph_drift", "[1.0, .inf]"),
])
def test_a_data_set_config_refuses_infinite_numbers_naming_the_key(tmp_path, loader, key,
                                                                   value):
    """The data sets' configs take no infinity or NaN either, as a scenario's do."""
    from tcaff_gtsam.eval import config

    path = tmp_path / "d.yaml"
    path.write_text(f"{key}: {value}\n")
    with pytest.raises(ConfigError, match=re.escape("d.yaml: ") + f".*{key}[.:]") as info:
        getattr(config, loader)(path)
    assert "finite number" in str(info.value)
