"""The `tcaff` command line."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from tcaff_gtsam.eval import cli
from tcaff_gtsam.eval.cli import app
from tcaff_gtsam.eval.config import CONFIG_DIR, MethodsConfig
from typer.main import get_command
from typer.testing import CliRunner

runner = CliRunner()
TCAFF = str(Path(sys.executable).parent / "tcaff")
COMMANDS = get_command(app).commands  # name -> click command


def help_of(command: str) -> str:
    """`tcaff COMMAND --help` as one line: wide enough that no help text wraps, runs of spaces
    collapsed."""
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "300"})
    assert result.exit_code == 0, result.output
    return " ".join(result.output.split())


def test_help_lists_the_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("align-maps", "make-maps", "study", "demo"):
        assert command in result.output


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_help_is_shown_whole(command):
    # rich reads "[s]" or "[m]" in a help text as markup and drops it.
    shown = help_of(command)
    for param in COMMANDS[command].params:
        if getattr(param, "help", None):
            assert " ".join(param.help.split()) in shown, (param.name, param.help)


def test_help_keeps_the_units():
    assert "Current time (s); default: the latest last_seen" in help_of("align-maps")
    assert "Centroid noise per axis (m)." in help_of("make-maps")


@pytest.mark.parametrize(("folder", "commands"), [
    ("scenarios", ["study"]), ("studies", ["study"]),
    ("methods", ["study", "kimera-multi", "mrclam"]),
    ("kimera_multi", ["kimera-multi"]), ("mrclam", ["mrclam"])])
def test_help_lists_every_shipped_config(folder, commands):
    names = sorted(path.stem for path in (CONFIG_DIR / folder).glob("*.yaml"))
    assert names
    for command in commands:
        shown = help_of(command)
        for name in names:
            assert re.search(rf"\b{name}\b", shown), (command, folder, name)


def test_cli_finds_the_configs_where_the_loader_does():
    assert cli._CONFIG_DIR.resolve() == CONFIG_DIR.resolve()


ALIGNER_DEFAULTS_PROBE = """
import dataclasses, json
import tcaff_gtsam.params as params

@dataclasses.dataclass(frozen=True, eq=False)
class Changed(params.FrameAlignerParams):
    kappa: float = 7.5
    dim: int = 3
    n_solutions: int = 9
    min_associations: int = 3
    covariance: str = "residual"
    clipper: params.ClipperParams = dataclasses.field(
        default_factory=lambda: params.ClipperParams(seed=11))

params.FrameAlignerParams = Changed
from typer.main import get_command
from tcaff_gtsam.eval.cli import app
print(json.dumps({p.name: p.default for p in get_command(app).commands["align-maps"].params}))
"""


def test_align_maps_defaults_come_from_the_aligner_params():
    done = subprocess.run([sys.executable, "-c", ALIGNER_DEFAULTS_PROBE], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    defaults = json.loads(done.stdout)
    assert {k: defaults[k] for k in ("kappa", "dim", "solutions", "min_associations",
                                     "covariance", "seed")} == {
        "kappa": 7.5, "dim": 3, "solutions": 9, "min_associations": 3,
        "covariance": "residual", "seed": 11}


REPORT = {"translation_error_m_mean": 0.12, "translation_error_m_std": 0.03,
          "heading_error_deg_mean": 1.25, "heading_error_deg_std": 10.5, "availability": 1.0,
          "correct_availability": 0.875, "false_accept": 0.125, "confident_false_accept": 0.0625,
          "nees_mean": 123456.0, "nees_under_95": 0.5,
          "time_to_first_correct_per_overlap_s_median": 14.0, "overlaps_found": 0.75,
          "judge_availability": 0.92, "ape_m": 0.05, "rpe_m": 0.04,
          "ms_per_pair_step": 12345.67}
#: a method without covariance or candidates, which no overlap found
BARE = {**REPORT, "nees_mean": None, "nees_under_95": None, "confident_false_accept": None,
        "judge_availability": None, "time_to_first_correct_per_overlap_s_median": None,
        "overlaps_found": 0.0}


def table_text(summary: dict, labels: dict, width: int) -> str:
    console = Console(width=width, record=True)
    console.print(cli._pooled_table(summary, labels))
    return console.export_text()


@pytest.mark.parametrize("width", [66, 80, 120])
def test_study_table_never_cuts_a_number(width):
    """Down to 66 columns (nine columns of numbers and the labels need that much)."""
    labels = {"tcaff": "TCAFF", "smoothed": "TCAFF+iSAM2 smoothed", "truth": "ground truth"}
    summary = {"ambiguous_grid_opposite": {"tcaff": REPORT, "smoothed": REPORT, "truth": BARE}}
    text = table_text(summary, labels, width)
    assert max(map(len, text.splitlines())) <= width
    for number in ("12345.67", "0.12", "0.03", "1.25", "10.50", "100", "88", "12.5", "6.2",
                   "1e+05", "50", "14", "75", "92", "0.05", "0.04"):
        assert re.search(rf"(?<![\d.]){re.escape(number)}(?![\d.e+])", text), (number, text)


def test_study_table_shows_the_new_figures_and_the_perfect_judge_once():
    labels = {"tcaff": "TCAFF", "smoothed": "TCAFF+iSAM2 smoothed", "truth": "ground truth"}
    summary = {"indoor": {"tcaff": REPORT, "smoothed": REPORT, "truth": BARE},
               "bare": dict.fromkeys(labels, BARE)}
    text = table_text(summary, labels, 140)
    lines = text.splitlines()
    row = next(line for line in lines if line.strip().startswith("TCAFF "))
    assert "12.5 (6.2) %" in row and "1e+05 (50 %)" in row and "14 (75 %)" in row
    truth = next(line for line in lines if line.strip().startswith("ground truth"))
    # no covariance: NEES "-", not 0; no overlap found: "-" seconds of 0 %
    assert "12.5 (-) %" in truth and "- (0 %)" in truth and " - " in truth
    judges = [line for line in lines if line.strip().startswith("perfect judge")]
    assert len(judges) == 1 and "92 (92) %" in judges[0]  # once, under indoor, not under bare
    assert lines.index(judges[0]) < next(k for k, line in enumerate(lines)
                                         if line.strip() == "bare")
    for header in ("false acc.", "(conf.)", "NEES", "(<95 %)", "1st correct", "per overlap"):
        assert header in text, header
    console = Console(width=100, record=True)
    console.print(cli._summary_table(summary, MethodsConfig(methods=["tcaff"])))
    key = " ".join(console.export_text().split())  # the key under the table, wrapped whole
    assert "NEES > 14.16" in key and "95 % bound 7.81" in key and "perfect judge" in key


def test_nees_cells_stay_short_however_large():
    cell = cli._nees_cell
    assert cell({"nees_mean": 2.987, "nees_under_95": 0.951}) == "2.99 (95 %)"
    assert cell({"nees_mean": 123.4, "nees_under_95": 0.0}) == "123 (0 %)"
    assert cell({"nees_mean": 4.2e7, "nees_under_95": 0.0}) == "4e+07 (0 %)"
    assert cell({"nees_mean": None, "nees_under_95": None}) == "-"


def test_make_maps_then_align_maps_finds_the_truth(tmp_path):
    result = runner.invoke(app, ["make-maps", str(tmp_path), "--seed", "3"])
    assert result.exit_code == 0, result.output
    truth = json.loads((tmp_path / "truth.json").read_text())["T_oi_oj"]
    result = runner.invoke(app, ["align-maps", str(tmp_path / "ego.npz"),
                                 str(tmp_path / "other.npz"), "--json"])
    assert result.exit_code == 0, result.output
    candidates = json.loads(result.output)
    assert candidates
    best = candidates[0]
    assert math.hypot(best["x"] - truth["x"], best["y"] - truth["y"]) < 0.6
    assert abs(best["theta"] - truth["theta"]) < math.radians(1.5)
    assert len(best["associations"]) >= 5
    table = runner.invoke(app, ["align-maps", str(tmp_path / "ego.npz"),
                                str(tmp_path / "other.npz")])
    assert "candidate alignments" in table.output


def test_align_maps_gives_one_registrations_covariance(tmp_path):
    """No filter follows the command, so its R is the registration's own (repeat_inflation
    = 0), which is smaller than the R the aligner gives a filter."""
    from tcaff_gtsam import FrameAligner, FrameAlignerParams
    from tcaff_gtsam.object_map import ObjectMap

    assert runner.invoke(app, ["make-maps", str(tmp_path), "--seed", "3"]).exit_code == 0
    ego, other = ObjectMap.load(tmp_path / "ego.npz"), ObjectMap.load(tmp_path / "other.npz")
    result = runner.invoke(app, ["align-maps", str(tmp_path / "ego.npz"),
                                 str(tmp_path / "other.npz"), "--json"])
    R = np.array(json.loads(result.output)[0]["R"])
    now = float(max(ego.last_seen.max(), other.last_seen.max()))
    single = FrameAligner(FrameAlignerParams(repeat_inflation=0.0)).measurements(ego, other, now)
    filtered = FrameAligner(FrameAlignerParams()).measurements(ego, other, now)
    np.testing.assert_allclose(R, single[0].R, rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(filtered[0].R - R) > 0)


def test_missing_map_is_a_clear_error(tmp_path, tcaff_main):
    done = tcaff_main("align-maps", str(tmp_path / "nope.npz"), str(tmp_path / "nope2.npz"))
    assert done.returncode == 2
    assert "no such map file" in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("dtype", ["bool", "complex128"])
def test_a_map_with_boolean_or_complex_centroids_is_a_clear_error(tmp_path, tcaff_main, dtype):
    """numpy used to take booleans as 0 and 1 without a word, and to drop the imaginary parts
    with a warning, and the rest was aligned."""
    import numpy as np

    runner.invoke(app, ["make-maps", str(tmp_path)])
    with np.load(tmp_path / "ego.npz") as data:
        arrays = {name: data[name] for name in data.files}
    bad = tmp_path / f"{dtype}.npz"
    np.savez(bad, **{**arrays, "centroids": (arrays["centroids"] + 1j).astype(dtype)})
    with warnings.catch_warnings():
        warnings.simplefilter("always")  # printed to stderr, not once per process
        done = tcaff_main("align-maps", str(tmp_path / "other.npz"), str(bad))
    assert done.returncode == 2
    assert done.stderr.strip() == (f"error: {bad}: array 'centroids' has dtype {dtype}, not "
                                   f"real numbers")


def test_bad_option_is_a_clear_error(tmp_path, tcaff_main):
    runner.invoke(app, ["make-maps", str(tmp_path)])
    done = tcaff_main("align-maps", str(tmp_path / "ego.npz"), str(tmp_path / "other.npz"),
                      "--dim", "5")
    assert done.returncode == 2
    assert "dim" in done.stderr and "Traceback" not in done.stderr


SCENARIOS = ["indoor_return", "same_direction", "opposite_directions", "four_robots",
             "ambiguous_grid", "indoor_rgbd", "mot"]


# every shipped scenario runs in the `paper` study below; here `--scenario` picks one, with
# and without people
@pytest.mark.parametrize("scenario", ["indoor_return", "mot"])
def test_study_runs_a_chosen_scenario(tmp_path, scenario):
    result = runner.invoke(app, ["study", "demo", "--scenario", scenario, "--duration", "12",
                                 "--workers", "1", "--output", str(tmp_path), "--no-figures"])
    assert result.exit_code == 0, result.output
    assert scenario in result.output and "TCAFF+iSAM2 smoothed" in result.output
    metrics = json.loads((tmp_path / "latest" / "metrics.json").read_text())
    assert list(metrics["summary"]) == [scenario]
    tracked = scenario == "mot"  # the only shipped scenario with people
    assert ("Tracking people together" in result.output) == tracked
    assert list(metrics["mot_summary"]) == ([scenario] if tracked else [])


@pytest.mark.parametrize("methods", ["default", "tcaff_only", "team"])
def test_study_runs_each_shipped_method_set(tmp_path, methods):
    result = runner.invoke(app, ["study", "demo", "-s", "indoor_return", "--methods", methods,
                                 "--duration", "12", "--output", str(tmp_path)])
    assert result.exit_code == 0, result.output
    figures = {p.name for p in (tmp_path / "latest" / "figures").glob("*.png")}
    assert "leave_and_return.png" in figures
    assert ("clipper_sweep.png" in figures) == (methods == "default")


@pytest.mark.slow
def test_demo_prints_every_table_and_draws_every_figure(tmp_path):
    """`make demo`'s job, every scenario shortened to 5 s (every table row and figure is
    there by then), in one process."""
    result = runner.invoke(app, ["demo", "--duration", "5", "--workers", "1", "--output",
                                 str(tmp_path)])
    assert result.exit_code == 0, result.output
    for name in SCENARIOS:
        assert name in result.output
    for row in ("TCAFF+iSAM2 smoothed", "CLIPPER k>=10", "Tracking people together",
                "no sharing"):
        assert row in result.output
    latest = tmp_path / "latest"
    assert (latest / "metrics.csv").is_file()
    figures = {p.name for p in (latest / "figures").glob("*.png")}
    assert figures == {"leave_and_return.png", "clipper_sweep.png", "scenarios.png",
                       "mot_mot.png", "mot_sweep.png",
                       *(f"errors_{name}.png" for name in SCENARIOS)}


@pytest.mark.slow
@pytest.mark.parametrize("study", ["paper"])  # demo: the test above
def test_study_runs_each_shipped_study(tmp_path, study):
    result = runner.invoke(app, ["study", study, "--seeds", "1", "--duration", "4",
                                 "--workers", "1", "--output", str(tmp_path), "--no-figures"])
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "latest" / "metrics.json").read_text())
    assert list(metrics["summary"]) == SCENARIOS
    assert list(metrics["mot_summary"]) == ["mot"]


def test_bad_study_config_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenarios: [indoor_return]\nworkers: 0\n")
    # the console script itself, once: the other one-line errors call its entry point in this
    # process
    done = subprocess.run([TCAFF, "study", str(bad)], capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip() == ("error: bad.yaml: workers: Input should be greater than or "
                                   "equal to 1 (got 0)")


# -- bad input ends in one line on stderr and exit status 2 -------------------------------------


def one_line_error(done: subprocess.CompletedProcess, *named: str) -> str:
    """The single stderr line of a refused command, which names each of `named`."""
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for name in named:
        assert name in lines[0], (name, lines[0])
    return lines[0]


BINARY = b"workers: 1\n\xff\xfe\x00\x81 not text"
DUPLICATE = "scenarios: [indoor_return]\nworkers: 1\nseeds: [0]\nworkers: 2\n"


@pytest.mark.parametrize("where", ["study", "scenario", "methods", "kimera-config"])
def test_a_binary_yaml_is_named_in_one_line(tmp_path, tcaff_main, where):
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(BINARY)
    args = {"study": ["study", str(bad)],
            "scenario": ["study", "demo", "-s", str(bad), "--output", str(tmp_path)],
            "methods": ["study", "demo", "--methods", str(bad), "--output", str(tmp_path)],
            "kimera-config": ["kimera-multi", "--data", str(tmp_path), "--config", str(bad),
                              "--output", str(tmp_path)]}[where]
    line = one_line_error(tcaff_main(*args), str(bad), "not a UTF-8 text file")
    assert line == f"error: {bad}: not a UTF-8 text file (byte 0xff at offset 11)"


@pytest.mark.parametrize("where", ["study", "scenario", "methods"])
def test_a_duplicate_yaml_key_is_named_in_one_line(tmp_path, tcaff_main, where):
    bad = tmp_path / "dup.yaml"
    if where == "study":
        bad.write_text(DUPLICATE)
        args = ["study", str(bad)]
    elif where == "scenario":
        text = (CONFIG_DIR / "scenarios" / "indoor_return.yaml").read_text()
        bad.write_text(text + "\nduration: 30\nduration: 40\n")
        args = ["study", "demo", "-s", str(bad), "--output", str(tmp_path)]
    else:
        bad.write_text("methods: [tcaff]\nmethods: [ground_truth]\n")
        args = ["study", "demo", "--methods", str(bad), "--output", str(tmp_path)]
    line = one_line_error(tcaff_main(*args), str(bad), "duplicate key")
    key = {"study": "workers", "scenario": "duration", "methods": "methods"}[where]
    assert f"duplicate key {key!r}" in line


@pytest.mark.parametrize(("command", "shipped"), [("study", "studies/demo.yaml"),
                                                 ("sweep", "sweeps/tau_window.yaml")])
def test_a_scenario_picked_beside_the_config_file_is_found(tmp_path, tcaff_main, monkeypatch,
                                                         command, shipped):
    """`study FOLDER/st.yaml -s near.yaml` takes near.yaml from the study file's folder, as the
    study's own list does, and `sweep FOLDER/sw.yaml -s near.yaml` from the sweep file's
    (picked twice here, so that it is refused once loaded, naming -s, rather than run); from
    the current folder only, it was "no such config file"."""
    folder = tmp_path / "configs"
    folder.mkdir()
    shutil.copy(CONFIG_DIR / shipped, folder / "config.yaml")
    shutil.copy(CONFIG_DIR / "scenarios" / "indoor_return.yaml", folder / "near.yaml")
    monkeypatch.chdir(tmp_path)
    line = one_line_error(tcaff_main(command, str(folder / "config.yaml"), "-s", "near.yaml",
                                     "-s", "near.yaml", "--output", str(tmp_path)),
                          "-s/--scenario")
    assert "picks scenario indoor_return a second time" in line


@pytest.mark.parametrize("command", ["study", "sweep"])
@pytest.mark.parametrize("again", ["indoor_return", "indoor_return.yaml"])
def test_a_scenario_picked_twice_names_the_option(tmp_path, tcaff_main, command, again):
    """The study's check that its scenarios' names are distinct blamed its YAML file (the
    sweep's study), where the scenario came twice from the command line."""
    if again.endswith(".yaml"):
        again = str(CONFIG_DIR / "scenarios" / again)
    config = {"study": "demo", "sweep": "tau_window"}[command]
    line = one_line_error(tcaff_main(command, config, "-s", "indoor_return", "-s", again,
                                     "--output", str(tmp_path)), "-s/--scenario", repr(again))
    assert "picks scenario indoor_return a second time" in line
    assert not any(tmp_path.iterdir())  # refused before anything ran


def test_the_loader_refuses_duplicates_but_keeps_merges():
    import yaml
    from tcaff_gtsam.eval.config import UniqueKeyLoader

    assert yaml.load("a: &b {x: 1}\nc:\n  <<: *b\n  x: 2\n", Loader=UniqueKeyLoader) == {
        "a": {"x": 1}, "c": {"x": 2}}
    with pytest.raises(yaml.YAMLError, match="duplicate key 'x'"):
        yaml.load("c: {x: 1, y: 2, x: 3}\n", Loader=UniqueKeyLoader)


def test_arbitrary_bytes_as_a_config_load_or_fail_in_one_line(tmp_path):
    """Whatever a study file holds, loading it gives a config or a one-line ConfigError."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from tcaff_gtsam.eval.config import load_study

    from tcaff_gtsam.errors import ConfigError

    path = tmp_path / "any.yaml"
    texts = st.one_of(st.binary(max_size=200),
                      st.text(alphabet=st.sampled_from(list("ab:-[]{},&*<\n #!0.'\"")),
                              max_size=80).map(str.encode))

    @settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
    @given(texts)
    def check(data: bytes) -> None:
        path.write_bytes(data)
        try:
            load_study(path)
        except ConfigError as exc:
            assert "\n" not in str(exc) and str(path.name) in str(exc)

    check()


@pytest.mark.parametrize("command", ["study", "demo", "kimera-multi", "mrclam", "make-maps"])
@pytest.mark.parametrize("kind", ["file", "under-a-file"])
def test_an_output_that_cannot_be_a_folder_is_refused_first(tmp_path, tcaff_main, command,
                                                             kind):
    taken = tmp_path / "taken"
    taken.write_text("keep me")
    out = taken if kind == "file" else taken / "sub"
    args = {"study": ["study", "demo", "--output", str(out)],
            "demo": ["demo", "--output", str(out)],
            "kimera-multi": ["kimera-multi", "--data", str(tmp_path), "--output", str(out)],
            "mrclam": ["mrclam", "--data", str(tmp_path), "--output", str(out)],
            "make-maps": ["make-maps", str(out)]}[command]
    option = "OUT_DIR" if command == "make-maps" else "--output"
    line = one_line_error(tcaff_main(*args), option, str(out))
    assert line.endswith("exists and is not a folder" if kind == "file"
                         else "not a writable folder (Not a directory)")
    assert taken.read_text() == "keep me"


@pytest.mark.parametrize(("args", "option"), [
    (["--noise", "-1"], "--noise"), (["--noise", "nan"], "--noise"),
    (["--overlap", "1.5"], "--overlap"), (["--objects", "-1"], "--objects"),
    (["--clutter", "-2"], "--clutter"), (["--seed", "-1"], "--seed"),
    (["--objects", "1000000"], "--objects"), (["--clutter", "10001"], "--clutter")])
def test_make_maps_options_are_checked(tmp_path, tcaff_main, args, option):
    line = one_line_error(tcaff_main("make-maps", str(tmp_path / "maps"), *args), option)
    assert line.startswith(f"error: {option} ")
    assert not (tmp_path / "maps").exists()


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    folder = tmp_path_factory.mktemp("maps")
    assert runner.invoke(app, ["make-maps", str(folder)]).exit_code == 0
    return str(folder / "ego.npz"), str(folder / "other.npz")


@pytest.mark.parametrize(("args", "option"), [
    (["--seed", "-1"], "--seed"), (["--kappa", "nan"], "--kappa"),
    (["--solutions", "0"], "--solutions"), (["--min-associations", "0"], "--min-associations"),
    # refused by max_associations' rule, an aligner field the command has no option for
    (["--min-associations", "100000"], "--min-associations"),
    (["--covariance", "bogus"], "--covariance"), (["--now", "inf"], "--now")])
def test_align_maps_options_are_named(maps, tcaff_main, args, option):
    line = one_line_error(tcaff_main("align-maps", *maps, *args), option)
    assert line.startswith(f"error: {option} ")


def test_align_maps_takes_a_now_on_the_maps_clock_and_refuses_another(maps, tcaff_main):
    """A --now more than `NOW_TOLERANCE` before the maps' latest last_seen (a time on another
    clock) used to make every object count as just seen; within it (clocks a little out of
    step) it finds what the maps' own time does (the objects' ages, and so the weights, differ
    by that second)."""
    from tcaff_gtsam.eval.cli.maps import NOW_TOLERANCE

    from tcaff_gtsam.object_map import ObjectMap

    latest = max(float(ObjectMap.load(m).last_seen.max()) for m in maps)
    own = json.loads(tcaff_main("align-maps", *maps, "--json").stdout)
    lagging = tcaff_main("align-maps", *maps, "--json", "--now", repr(latest - NOW_TOLERANCE))
    assert lagging.returncode == 0, lagging.stderr
    assert own and [c["associations"] for c in json.loads(lagging.stdout)] == [
        c["associations"] for c in own]
    for now in (latest - NOW_TOLERANCE - 1e-6, latest - 1e9, 0.0):  # the maps: 85-100 s
        line = one_line_error(tcaff_main("align-maps", *maps, "--now", repr(now)), "--now",
                              "before the latest last_seen")
        assert line.startswith(f"error: --now {now!r}: is ")


def test_align_maps_seed_message():
    from tcaff_gtsam.errors import ConfigError

    with pytest.raises(ConfigError) as caught:
        cli._aligner_params(20.0, 2, 5, 3, "constant", -1)
    assert str(caught.value) == "--seed -1: must be an int >= 0"


@pytest.mark.parametrize("value", ["inf", "nan", "0", "-3"])
@pytest.mark.parametrize("command", ["study", "demo", "kimera-multi", "mrclam"])
def test_duration_must_be_finite_and_positive(tmp_path, tcaff_main, command, value):
    args = {"study": ["study", "demo"], "demo": ["demo"],
            "kimera-multi": ["kimera-multi", "--data", str(tmp_path)],
            "mrclam": ["mrclam", "--data", str(tmp_path)]}[command]
    line = one_line_error(tcaff_main(*args, "--duration", value, "--output",
                                     str(tmp_path / "out")), "--duration")
    assert line.endswith("must be a finite number of seconds >= 1")
    assert not (tmp_path / "out").exists()


# -- Ctrl-C ---------------------------------------------------------------------------------


def test_ctrl_c_while_the_workers_start_is_one_line_and_exit_130(tmp_path):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while the workers
    are still importing the stack: one line, exit status 130, the results folder written.
    The runs are whole (300 s, seconds each), so that on a fast machine they are not all
    done before the signal."""
    import os
    import signal
    import time

    out = tmp_path / "out"
    command = [TCAFF, "study", "demo", "-s", "indoor_return", "--seeds", "3", "--workers", "2",
               "--output", str(out), "--no-figures"]
    # Ctrl-C as in a terminal, whatever the suite was started with: a shell's background job
    # (CI's, say) starts with it ignored, and a process that starts so never sees it
    terminal = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                "os.execv(sys.argv[1], sys.argv[1:])")
    proc = subprocess.Popen([sys.executable, "-c", terminal, *command], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    while not (out.is_dir() and any(out.iterdir())) and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)  # the manager and the workers are starting
    os.killpg(proc.pid, signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and re.fullmatch(r"interrupted: \d of 3 runs finished, kept in .+",
                                            lines[0]), stderr
    folder = Path(lines[0].split(" kept in ")[1])
    assert json.loads((folder / "metrics.json").read_text())["interrupted"] is True


def test_the_study_workers_ignore_ctrl_c_from_their_start():
    """... and a process of their context loads no more than it runs: the study's queue
    manager (which runs no job) starts without importing the stack."""
    import signal

    from tcaff_gtsam.eval.quiet_spawn import QuietSpawnContext

    # as in a terminal, whatever the test runner was started with (a background job ignores it)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        context = QuietSpawnContext()
        with context.Pool(1) as pool:
            assert pool.apply(signal.getsignal, (signal.SIGINT,)) == signal.SIG_IGN
            loaded = pool.apply(eval, ("sorted(__import__('sys').modules)",))
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    assert "tcaff_gtsam.eval.quiet_spawn" in loaded
    assert not {"numpy", "tcaff_gtsam.eval.jobs", "tcaff_gtsam.eval.executor"} & set(loaded)


def test_a_worker_that_starts_after_its_study_stopped_ends_quietly(capfd, tmp_path):
    """Ctrl-C while the workers start: a worker still importing once the study has given up
    waiting for it finds the study's queue closed, and ends without a traceback (which would
    follow the study's one-line message) and without taking a job."""
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    from tcaff_gtsam.eval import executor
    from tcaff_gtsam.eval.quiet_spawn import QuietSpawnContext

    context = QuietSpawnContext()
    manager = context.Manager()
    updates = manager.Queue()
    manager.shutdown()  # the stopped study closed its queue
    taken = tmp_path / "taken"
    capfd.readouterr()
    # the study's pool: a worker whose initializer returns takes the queued job, which
    # leaves the file behind
    pool = ProcessPoolExecutor(max_workers=1, mp_context=context,
                               initializer=executor._announce, initargs=(updates, 1))
    try:
        job = pool.submit(taken.touch)
        with pytest.raises(BrokenProcessPool):
            job.result(timeout=120)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    assert not taken.exists()
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize(("args", "named"), [
    (["study", "--seeds", "0"], ["--seeds", "tcaff study --help"]),
    (["study", "--workers", "x"], ["--workers"]),
    (["study", "--bogus"], ["--bogus"]),
    (["make-maps"], ["out_dir", "tcaff make-maps --help"]),
    (["nocmd"], ["nocmd", "tcaff --help"]),
])
def test_a_bad_option_or_argument_is_one_line(tcaff_main, args, named):
    one_line_error(tcaff_main(*args), *named)


def test_help_still_works_and_tcaff_alone_shows_it(tcaff_main, capsys):
    assert tcaff_main("--help").returncode == 0
    alone = tcaff_main()
    assert alone.returncode == 2 and "error" not in alone.stderr


def test_advise_kappa_prints_the_table_writes_it_and_follows_the_drift(tmp_path):
    """The advice is the span the table shows within epsilon / 2; faster drift advises a
    shorter span, and drift past the bound at 5 s advises none."""
    out = tmp_path / "kappa.csv"
    result = runner.invoke(app, ["advise-kappa", "--seeds", "2", "--minutes", "6", "--csv",
                                 str(out)])
    assert result.exit_code == 0, result.output
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert table.shape == (12, 4)
    np.testing.assert_allclose(table[:, 3], table[:, 1:3].max(axis=1))
    within = table[:, 0][np.cumprod(table[:, 3] <= 0.125).astype(bool)]
    assert f"kappa: {within[-1]:g} s" in result.output
    slow = runner.invoke(app, ["advise-kappa", "--seeds", "1", "--minutes", "6",
                               "--heading-rw", "0.1", "--scale-std", "0.001"])
    assert float(slow.output.split("kappa: ")[1].split()[0]) > within[-1]
    fast = runner.invoke(app, ["advise-kappa", "--seeds", "1", "--minutes", "6",
                               "--heading-rw", "60"])
    assert "kappa: no span keeps the maps within epsilon / 2" in " ".join(fast.output.split())
    still = runner.invoke(app, ["advise-kappa", "--seeds", "1", "--minutes", "6", "--speed",
                                "0"])  # a robot that stays put: every span is within the bound
    assert "kappa: 300 s or more (the longest span tried" in " ".join(still.output.split())


@pytest.mark.parametrize(("args", "option"), [
    (["--heading-rw", "nan"], "--heading-rw"), (["--speed", "-1"], "--speed"),
    (["--epsilon", "0"], "--epsilon"), (["--seeds", "0"], "--seeds"),
    (["--minutes", "inf"], "--minutes"), (["--range", "-0.5"], "--range")])
def test_advise_kappa_refuses_bad_values_in_one_line(args, option, tcaff_main):
    one_line_error(tcaff_main("advise-kappa", *args), option)


@pytest.mark.parametrize("args", [
    ["mrclam", "--data", "missing", "--seed", "-1"],
    ["rgbd", "--data", "missing", "--seed", "-3"],
    ["node", "--robot", "r0", "--scenario", "four_robots", "--seed", "-1"],
    ["node", "--robot", "r0", "--scenario", "four_robots", "--drop-seed", "-2"],
    ["team", "--scenario", "four_robots", "--seed", "-1"],
    ["team", "--scenario", "four_robots", "--silence", "0"],
    ["team", "--scenario", "four_robots", "--drop-share", "1"],
    ["rgbd", "--data", "missing", "--fps", "0"],
], ids=lambda args: f"{args[0]} {args[-2]}")
def test_negative_seeds_and_a_zero_frame_rate_are_refused_in_one_line(args, tcaff_main):
    """Before any data is read or process started, naming the option (a negative seed used
    to end in numpy's ValueError deep inside the random generator)."""
    one_line_error(tcaff_main(*args), args[-2])


# -- inputs that used to end in a raw traceback, a hang or a wrong exit status ------------------


def test_advise_kappa_refuses_a_csv_it_cannot_write_and_too_many_drives(tmp_path, tcaff_main):
    folder = tmp_path / "a_folder"
    folder.mkdir()
    one_line_error(tcaff_main("advise-kappa", "--seeds", "1", "--minutes", "5", "--csv",
                              str(folder)), "--csv", "is a folder")
    # printed first, then written: the table is shown, the file's failure named
    done = tcaff_main("advise-kappa", "--seeds", "1", "--minutes", "5", "--csv", "/dev/full")
    assert done.returncode == 2 and "span [s]" in done.stdout
    assert done.stderr.strip().startswith("error: --csv '/dev/full': could not be written")
    one_line_error(tcaff_main("advise-kappa", "--seeds", "1000000000000", "--minutes", "5"),
                   "--seeds", "[1, 100]")


def test_make_maps_refuses_a_folder_where_a_file_goes(tmp_path, tcaff_main):
    (tmp_path / "truth.json").mkdir()
    one_line_error(tcaff_main("make-maps", str(tmp_path)), "OUT_DIR", "truth.json")
    assert not (tmp_path / "ego.npz").exists()  # refused before anything is written


@pytest.mark.parametrize(("command", "args", "option"), [
    # str.isdigit takes superscripts, int() does not
    ("mrclam", ["--pairs", "1:\u00b2"], "--pairs"),
    ("mrclam", ["--kappa", "-3"], "--kappa"), ("mrclam", ["--kappa", "nan"], "--kappa"),
    ("rgbd", ["--robots", "0:\u00b2,0:5"], "--robots"),
    # a span of 40 frames at 1e-3 frames a second: 40 000 exchanges of one map
    ("rgbd", ["--fps", "1e-3"], "--fps"), ("rgbd", ["--fps", "1e-300"], "--fps"),
])
def test_dataset_options_a_user_can_mistype_are_named(tmp_path, tcaff_main, command, args,
                                                      option):
    data = tmp_path / "data"
    data.mkdir()
    line = one_line_error(tcaff_main(command, "--data", str(data), "--output",
                                     str(tmp_path / "out"), *args), option)
    assert line.startswith(f"error: {option} ")


@pytest.mark.parametrize(("args", "option"), [
    (["--start-at", "nan"], "--start-at"), (["--start-at", "1e15"], "--start-at"),
    (["--clock-offset", "1e300"], "--clock-offset"), (["--clock-offset", "nan"],
                                                        "--clock-offset")])
def test_node_times_are_checked_before_it_starts(tmp_path, tcaff_main, args, option):
    line = one_line_error(tcaff_main("node", "--robot", "r0", "--scenario", "indoor_return",
                                     "--output", str(tmp_path / "out"), *args), option)
    assert line.startswith(f"error: {option} ")


def test_node_refuses_a_state_that_is_a_file(tmp_path, tcaff_main):
    taken = tmp_path / "state"
    taken.write_text("keep me")
    one_line_error(tcaff_main("node", "--robot", "r0", "--scenario", "indoor_return",
                              "--output", str(tmp_path / "out"), "--state", str(taken)),
                   "--state")
    assert taken.read_text() == "keep me"


@pytest.mark.parametrize("command", ["demo", "sweep"])
def test_workers_beyond_the_limit_are_refused_as_the_option(tmp_path, tcaff_main, command):
    args = ["demo"] if command == "demo" else ["sweep", "tau_window"]
    done = tcaff_main(*args, "--workers", "1000", "--output", str(tmp_path / "out"))
    assert done.returncode == 2
    assert "--workers" in done.stderr and "64" in done.stderr
