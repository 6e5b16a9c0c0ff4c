"""YAML configuration of scenarios, method sets and studies, validated with pydantic.

Unknown keys, wrong types and out-of-range values are rejected with a `ConfigError` whose one-line
message names the key's path, for example
`indoor_return.yaml: layout.room: Input should be greater than 0 (got -1)`.

A study names its scenarios and method set either by the name of a file shipped in
`eval/configs/` (`indoor_return`, `default`) or by a path, or holds them inline. The effective
configuration a study writes next to its results has everything inline and loads again as is.

Settings of an algorithm are not mirrored here: a key that holds them is validated by building
the algorithm's parameter dataclass (`FrameAlignerParams`, `TCAFFParams`, `GraphParams`,
`TrackerParams`; `MapperParams` for `mapping.nu` and `mapping.kappa`) from the keys given, so
its defaults and rules are the only ones, and its `ConfigError` comes out with the key's path.

The models live in modules by subject and are re-exported here, the public module:
`config_base` (the model base, shared validators, YAML reading and error messages),
`config_scenario`, `config_methods`, `config_study` (studies and sweeps) and `config_datasets`
(Kimera-Multi, MRCLAM, RGB-D). The loaders below resolve shipped names in `CONFIG_DIR`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from tcaff_gtsam.mapping.mapper import MapperParams  # noqa: F401  (re-exported)

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.params import (  # noqa: F401  (re-exported)
    FrameAlignerParams,
    GraphParams,
    ParameterError,
    TCAFFParams,
)

from .config_base import (  # noqa: F401  (re-exported)
    _LAYOUT_KINDS,
    GraphDrift,
    UniqueKeyLoader,
    _build,
    _check_drift,
    _DuplicateKeyError,
    _EntryError,
    _format,
    _Model,
    _params,
    _path,
    _plain,
    _read_yaml,
    _rule_of,
    _validate,
)
from .config_datasets import (  # noqa: F401  (re-exported)
    ExtrinsicsConfig,
    KappaConfig,
    KimeraMultiConfig,
    MrclamConfig,
    RgbdConfig,
    RgbdRigConfig,
    TopicsConfig,
    VioDriftConfig,
    _MapSpan,
)
from .config_methods import (  # noqa: F401  (re-exported)
    _PER_RUN,
    IcpConfig,
    MethodsConfig,
    ScoringConfig,
    ThresholdConfig,
    _Aligner,
    _Graph,
    _Tcaff,
)
from .config_scenario import (  # noqa: F401  (re-exported)
    CameraConfig,
    GridLayout,
    IndoorReturnLayout,
    Layout,
    MappingConfig,
    OdometryDrift,
    PathLayout,
    PedestriansConfig,
    PersonDetectorConfig,
    Range,
    RoomLayout,
    ScenarioConfig,
    SensorConfig,
    _check_range,
    _Detector,
    _Tracker,
)
from .config_study import (  # noqa: F401  (re-exported)
    SWEEP_ROOTS,
    StudyConfig,
    SweepConfig,
    _check_sweep_path,
)
from .registry import METHODS  # noqa: F401  (re-exported)
from .tracker import TrackerParams  # noqa: F401  (re-exported)

__all__ = [
    "CONFIG_DIR",
    "KimeraMultiConfig",
    "MethodsConfig",
    "MrclamConfig",
    "RgbdConfig",
    "ScenarioConfig",
    "StudyConfig",
    "SweepConfig",
    "UniqueKeyLoader",
    "apply_settings",
    "load_kimera_multi",
    "load_methods",
    "load_mrclam",
    "load_rgbd",
    "load_scenario",
    "load_study",
    "load_sweep",
    "override",
]

CONFIG_DIR = Path(__file__).parent / "configs"


# -- loading -----------------------------------------------------------------------------------


def _resolve(ref: str, folder: str) -> Path:
    """A shipped config's name (`indoor_return`) or a path to a YAML file."""
    path = Path(ref)
    if path.suffix in (".yaml", ".yml") or path.parent != Path("."):
        return path
    shipped = CONFIG_DIR / folder / f"{ref}.yaml"
    if not shipped.is_file():
        names = sorted(p.stem for p in (CONFIG_DIR / folder).glob("*.yaml"))
        kind = {"scenarios": "scenario", "methods": "method set", "studies": "study",
                "kimera_multi": "Kimera-Multi test", "mrclam": "MRCLAM evaluation",
                "rgbd": "RGB-D evaluation", "sweeps": "sweep"}[folder]
        found = (f" ({ref} is a folder; a config is a .yaml file)" if path.is_dir() else
                 f" ({ref} is not a .yaml file)" if path.exists() else "")
        raise ConfigError(f"no {kind} config named {ref!r}{found}; shipped: "
                          f"{', '.join(names)}")
    return shipped


def _near(ref: str, folder: Path | None) -> str:
    """`ref`, or the YAML file of that relative path in `folder` (a config's own folder) when
    it is there."""
    path = Path(ref)
    if folder is not None and path.suffix in (".yaml", ".yml") and not path.is_absolute():
        if (folder / path).is_file():
            return str(folder / path)
    return ref


def load_scenario(ref: str | Path) -> ScenarioConfig:
    """A scenario by shipped name or path."""
    path = _resolve(str(ref), "scenarios")
    return _validate(ScenarioConfig, _read_yaml(path), path.name)


def load_methods(ref: str | Path) -> MethodsConfig:
    """A method set by shipped name or path."""
    path = _resolve(str(ref), "methods")
    return _validate(MethodsConfig, _read_yaml(path), path.name)


def load_study(ref: str | Path, overrides: dict[str, Any] | None = None) -> StudyConfig:
    """A study by shipped name or path, with its scenarios and method set loaded inline.

    Args:
        overrides: top-level keys replacing the file's (validated like the file).
    """
    path = _resolve(str(ref), "studies")
    data = _read_yaml(path)
    picked = bool(overrides) and isinstance(data, dict) and "scenarios" in overrides
    if picked:  # the file's durations checked against its own scenarios
        resolve_study(_validate(StudyConfig, data, path.name), path.parent, source=path.name)
    if overrides and isinstance(data, dict):
        data = {**data, **overrides}
    # scenarios picked from the file's keep their caps; its other caps are dropped
    return resolve_study(_validate(StudyConfig, data, path.name), path.parent, strict=not picked,
                         source=path.name)


def load_sweep(ref: str | Path) -> tuple[SweepConfig, StudyConfig]:
    """A sweep by shipped name or path, and its base study resolved (scenarios and method set
    inline, the sweep's seeds when it gives them)."""
    path = _resolve(str(ref), "sweeps")
    sweep = _validate(SweepConfig, _read_yaml(path), path.name)
    if isinstance(sweep.study, StudyConfig):
        study = resolve_study(sweep.study, path.parent, source=f"{path.name}: study")
    else:
        study = load_study(_near(sweep.study, path.parent))
    if sweep.seeds is not None:
        study = study.model_copy(update={"seeds": sweep.seeds})
    return sweep, study


def apply_settings(config: ScenarioConfig | MethodsConfig, settings: dict[str, Any],
                   source: str) -> Any:
    """`config` with some settings changed, validated like a file.

    Args:
        settings: dotted path -> value; the first part of each path (`methods`, `scenario`)
            names the config and is skipped.
        source: names the settings in errors (e.g. "tau_window.yaml").
    Raises:
        ConfigError: a path that `config` does not have, or a value it refuses, naming the
            path and the value.
    """
    data = config.model_dump(mode="json")
    label = ", ".join(f"{path} = {value!r}" for path, value in settings.items())
    for path, value in settings.items():
        keys = path.split(".")[1:]
        node = data
        for depth, key in enumerate(keys[:-1]):
            child = node.get(key) if isinstance(node, dict) else None
            if not isinstance(child, dict):
                what = "has no key" if not isinstance(node, dict) or key not in node else (
                    f"has {key} = {child!r}, nothing to set inside")
                where = getattr(config, "name", type(config).__name__)
                raise ConfigError(f"{source}: {path}: {where} {what} "
                                  f"{'.'.join(keys[:depth + 1])!r}")
            node = child
        node[keys[-1]] = value
    return _validate(type(config), data, f"{source}: {label}")


def resolve_study(study: StudyConfig, folder: Path | None = None, strict: bool = True,
                  source: str | None = None) -> StudyConfig:
    """The same study with every scenario and the method set inline, each scenario no longer
    than the study's `durations` give for its name (which keeps the entries of the scenarios it
    runs); relative YAML paths are taken from `folder` (the study file's) when the file is there.

    Args:
        strict: a `durations` entry naming none of the scenarios is a ConfigError (a typo);
            False where the command line picked some of a study's scenarios (`-s`).
        source: names the study in errors (its file); by default "study NAME".
    """
    source = source or f"study {study.name!r}"
    scenarios = [s if isinstance(s, ScenarioConfig) else load_scenario(_near(s, folder))
                 for s in study.scenarios]
    names = [s.name for s in scenarios]
    if len(set(names)) != len(names):
        raise ConfigError(f"{source}: scenario names must be distinct, got {names}")
    unknown = sorted(set(study.durations) - set(names))
    if strict and unknown:
        raise ConfigError(f"{source}: durations names {unknown}, which are not among "
                          f"its scenarios {names}")
    scenarios = [s.model_copy(update={"duration": min(s.duration, study.durations[s.name])})
                 if s.name in study.durations else s for s in scenarios]
    methods = (study.methods if isinstance(study.methods, MethodsConfig)
               else load_methods(_near(study.methods, folder)))
    durations = {name: study.durations[name] for name in names if name in study.durations}
    return study.model_copy(update={"scenarios": scenarios, "methods": methods,
                                    "durations": durations})


def _load_with_methods(model: type[_Model], ref: str | Path, folder: str) -> Any:
    path = _resolve(str(ref), folder)
    config = _validate(model, _read_yaml(path), path.name)
    if isinstance(config.methods, str):
        config = config.model_copy(
            update={"methods": load_methods(_near(config.methods, path.parent))})
    return config


def override(config: _Model, source: str, **updates: Any) -> Any:
    """`config` with some top-level keys replaced (None values are ignored), validated like a
    file; errors name `source` (e.g. "command line")."""
    data = {name: getattr(config, name) for name in type(config).model_fields}
    data.update({k: v for k, v in updates.items() if v is not None})
    return _validate(type(config), data, source)


def load_kimera_multi(ref: str | Path) -> KimeraMultiConfig:
    """A Kimera-Multi test by shipped name (`same_direction`) or path, its method set loaded
    inline."""
    return _load_with_methods(KimeraMultiConfig, ref, "kimera_multi")


def load_mrclam(ref: str | Path) -> MrclamConfig:
    """An MRCLAM evaluation by shipped name (`default`) or path, its method set loaded
    inline."""
    return _load_with_methods(MrclamConfig, ref, "mrclam")


def load_rgbd(ref: str | Path) -> RgbdConfig:
    """An RGB-D sequence evaluation by shipped name (`default`) or path, its method set loaded
    inline."""
    return _load_with_methods(RgbdConfig, ref, "rgbd")


def dump_study(study: StudyConfig) -> str:
    """YAML of a resolved study, loadable again with `load_study`."""
    return yaml.safe_dump(study.model_dump(mode="json"), sort_keys=False)

