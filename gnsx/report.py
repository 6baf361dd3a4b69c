"""Kept for now so that `python -m gnsx.report` still works:
the tool is :mod:`gnsx.evaluation.report` (README, "Code structure")."""

import runpy

if __name__ == "__main__":
    runpy.run_module("gnsx.evaluation.report", run_name="__main__", alter_sys=True)
