"""`python -m tcaff_gtsam`: the `tcaff` command line.

The command line belongs to the evaluation layer, which the core does not import: it is found
by the `tcaff` entry point the package declares (pyproject.toml, [project.scripts]).
"""

from importlib.metadata import entry_points

if __name__ == "__main__":
    (tcaff,) = entry_points(group="console_scripts", name="tcaff")
    tcaff.load()()
