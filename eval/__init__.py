"""Evaluation: simulation, data sets, metrics, the comparison study and the `tcaff` CLI."""
