"""The registry of compared methods, keyed by name: what each method produces and how its
estimates are named and drawn. Data only (its runners live in `methods/` and are imported when a
run needs them), so configs can check method names without loading any runner.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

from tcaff_gtsam.errors import ConfigError

if TYPE_CHECKING:
    from .config import MethodsConfig

__all__ = ["METHODS", "Estimate", "Method", "describe", "estimate_names", "shown_streams"]


@dataclass(frozen=True)
class Estimate:
    """How one estimate stream is named in tables and drawn.

    Attributes:
        label: printed name; `{k}` is the swept value of a swept stream.
        color, line: matplotlib colour and line style.
        causal: built only from what was known at each step (usable online, e.g. for tracking).
        judged: built from the candidates the default TCAFF filter is offered (a job's
            cand_z_<p>): its reports carry the perfect judge of those candidates
            (`metrics.perfect_judge`), the availability any filter of them could reach.
    """

    label: str
    color: str
    line: str = "-"
    causal: bool = True
    judged: bool = False


@dataclass(frozen=True)
class Method:
    """A registered method.

    Attributes:
        runner: "module:Class" of its `MethodRunner`, relative to this package.
        streams: suffix -> `Estimate`; a stream is named method name + suffix. A suffix with
            `{k}` gives one stream per value of the method set's list `swept`.
        needs_truth: it needs the true alignment at every step.
        swept: the `MethodsConfig` field a `{k}` suffix takes its values from.
        shown: the `MethodsConfig` field holding the one swept value tables and figures show.
    """

    runner: str
    streams: dict[str, Estimate]
    needs_truth: bool = False
    swept: str | None = None
    shown: str | None = None


METHODS: dict[str, Method] = {
    "tcaff": Method("tcaff:TcaffRunner", {"": Estimate("TCAFF", "tab:red", judged=True)}),
    # the released preset takes every candidate, unchecked: not those the judge sees
    "tcaff_reference": Method("tcaff:ReferenceRunner", {
        "": Estimate("TCAFF reference", "tab:orange", "--")}),
    "tcaff_team": Method("tcaff:TeamRunner", {
        "": Estimate("TCAFF+team", "tab:olive", judged=True)}),
    "tcaff_isam2": Method("tcaff:GraphRunner", {
        "_causal": Estimate("TCAFF+iSAM2 causal", "tab:purple", judged=True),
        "_smoothed": Estimate("TCAFF+iSAM2 smoothed", "tab:pink", ":", causal=False,
                              judged=True)}),
    "clipper": Method("baselines:ClipperRunner", {
        "_k{k}": Estimate("CLIPPER k>={k}", "tab:blue")}, swept="clipper_k",
        shown="clipper_k_shown"),
    "icp": Method("baselines:IcpRunner", {"": Estimate("ICP, true init", "tab:brown")},
                  needs_truth=True),
    "ground_truth": Method("baselines:TruthRunner", {
        "": Estimate("ground truth", "tab:green")}, needs_truth=True),
}


def _streams(name: str, methods: MethodsConfig) -> list[str]:
    method = METHODS[name]
    out = []
    for suffix in method.streams:
        if "{k}" in suffix:
            out += [name + suffix.format(k=k) for k in getattr(methods, method.swept)]
        else:
            out.append(name + suffix)
    return out


def estimate_names(methods: MethodsConfig) -> list[str]:
    """The estimate streams a method set produces, in table order."""
    return [stream for name in methods.methods for stream in _streams(name, methods)]


def shown_streams(methods: MethodsConfig) -> list[str]:
    """The streams tables and figures show: every stream, but of a swept method only the one
    of the value the set shows (e.g. `clipper_k_shown`)."""
    shown = []
    for name in methods.methods:
        method = METHODS[name]
        if method.swept is None:
            shown += _streams(name, methods)
        else:
            k = getattr(methods, method.shown)
            shown += [name + suffix.format(k=k) for suffix in method.streams]
    return shown


def describe(stream: str) -> Estimate:
    """The `Estimate` of a stream name, its label filled in.

    Raises:
        ConfigError: no registered method produces a stream of that name.
    """
    for name, method in METHODS.items():
        for suffix, estimate in method.streams.items():
            if "{k}" not in suffix:
                if stream == name + suffix:
                    return estimate
                continue
            head, tail = (name + suffix).split("{k}")
            match = re.fullmatch(re.escape(head) + r"(-?\d+)" + re.escape(tail), stream)
            if match:
                return Estimate(estimate.label.format(k=match.group(1)), estimate.color,
                                estimate.line, estimate.causal, estimate.judged)
    raise ConfigError(f"no method produces an estimate named {stream!r}; methods: "
                      f"{', '.join(METHODS)}")
