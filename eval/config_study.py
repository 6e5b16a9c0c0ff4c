"""Study and sweep configuration (`config`): a study runs scenarios x a method set x seeds; a
sweep runs a base study at several points of dotted parameter paths into the method set or the
scenarios (a grid of every combination, or a list of points).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, field_validator, model_validator

from .config_base import FILE_NAME, _Model
from .config_methods import MethodsConfig
from .config_scenario import MAX_DURATION, ScenarioConfig


class StudyConfig(_Model):
    """Scenarios x methods x seeds."""

    name: str = Field("study", min_length=1, pattern=FILE_NAME)
    scenarios: list[str | ScenarioConfig] = Field(min_length=1)
    methods: str | MethodsConfig = "default"
    seeds: list[int] = Field(default_factory=lambda: [0], min_length=1)
    workers: int = Field(2, ge=1, le=64)
    output: str = "results"
    durations: dict[str, Annotated[float, Field(ge=1, le=MAX_DURATION)]] = Field(
        default_factory=dict,
        description="scenario name -> s: run that scenario at most this long (a quick study)")

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, value: list[int]) -> list[int]:
        if any(s < 0 for s in value) or len(set(value)) != len(value):
            raise ValueError(f"seeds must be distinct ints >= 0, got {value}")
        return value


#: where a swept parameter's dotted path points: into the method set, or into every scenario
SWEEP_ROOTS = ("methods", "scenario")


class SweepConfig(_Model):
    """A base study run at several parameter points.

    A parameter is a dotted path into the method set (`methods.tcaff.tau`) or into every
    scenario of the study (`scenario.window`, `scenario.mapping.kappa`). `grid` runs every
    combination of its values; `points` lists the points one by one (each setting the same
    parameters). The study as given (no parameter changed) is the default point.
    """

    name: str = Field(min_length=1, pattern=FILE_NAME)
    description: str = ""
    study: str | StudyConfig = Field(description="the base study: shipped name, path or inline")
    grid: dict[str, list[Any]] | None = Field(None, description="path -> values, every combination")
    points: list[dict[str, Any]] | None = Field(None, description="path -> value, one per point")
    seeds: list[int] | None = Field(None, min_length=1, description="default: the study's")
    method: str = Field("tcaff", description="the estimate the report's table and figures show")
    output: str = Field("results/sweeps", description="results go to OUTPUT/<name>/")

    @field_validator("grid")
    @classmethod
    def _grid(cls, value: dict[str, list[Any]] | None) -> dict[str, list[Any]] | None:
        if value is None:
            return value
        if not value:
            raise ValueError("needs at least one parameter path")
        for path, values in value.items():
            _check_sweep_path(path)
            if not values:
                raise ValueError(f"{path}: needs at least one value")
            if len({repr(v) for v in values}) != len(values):
                raise ValueError(f"{path}: values must not repeat, got {values}")
        return value

    @field_validator("points")
    @classmethod
    def _points(cls, value: list[dict[str, Any]] | None) -> list[dict[str, Any]] | None:
        if value is None:
            return value
        if not value:
            raise ValueError("needs at least one point")
        for k, point in enumerate(value):
            if not point:
                raise ValueError(f"point {k} sets no parameter")
            for path in point:
                _check_sweep_path(path)
            if set(point) != set(value[0]):
                raise ValueError(f"point {k} sets {sorted(point)}; every point must set the "
                                 f"first one's {sorted(value[0])}")
        return value

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, value: list[int] | None) -> list[int] | None:
        if value is not None and (any(s < 0 for s in value) or len(set(value)) != len(value)):
            raise ValueError(f"seeds must be distinct ints >= 0, got {value}")
        return value

    @model_validator(mode="after")
    def _one_way(self) -> SweepConfig:
        if (self.grid is None) == (self.points is None):
            raise ValueError("give either grid (every combination) or points (a list)")
        return self

    @property
    def parameters(self) -> list[str]:
        """The swept paths, in the file's order."""
        return list(self.grid if self.grid is not None else self.points[0])  # type: ignore[index]


def _check_sweep_path(path: str) -> None:
    root, _, rest = path.partition(".")
    if root not in SWEEP_ROOTS or not rest or not all(path.split(".")):
        raise ValueError(f"{path}: a parameter path is methods.<key>[.<key>...] or "
                         f"scenario.<key>[.<key>...]")
