"""`python -m tcaff_gtsam`: the `tcaff` command line."""

from tcaff_gtsam.eval.cli import main

if __name__ == "__main__":
    main()
