"""Kept for now so that `python -m gnsx.pretrained` still works:
the tool is :mod:`gnsx.training.export` (README, "Code structure")."""

import runpy

if __name__ == "__main__":
    runpy.run_module("gnsx.training.export", run_name="__main__", alter_sys=True)
