"""`python -m tcaff_gtsam.eval.cli`: the `tcaff` command (the team starts its nodes so)."""

from . import main

main()
