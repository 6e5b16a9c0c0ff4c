"""A simulator that fails for one scenario, for the tests of what a study or a sweep keeps
when one of its runs fails."""

from __future__ import annotations

from tcaff_gtsam.eval import jobs as jobs_module


def fail_simulating(monkeypatch, scenario: str, seed: int | None = None):
    """Make the jobs' `simulate` raise RuntimeError("sensor exploded") for `scenario` (only
    its `seed` when given; every other run as before); returns the real `simulate`."""
    real = jobs_module.simulate

    def simulate(config, run_seed, progress=None):
        if config.name == scenario and seed in (None, run_seed):
            raise RuntimeError("sensor exploded")
        return real(config, run_seed, progress)

    monkeypatch.setattr(jobs_module, "simulate", simulate)
    return real
