"""``python -m gnsx.evaluation.report <sweep dir>``: the sweep report (:func:`gnsx.evaluation.report.main`)."""

from gnsx.core.cli import run_main
from gnsx.evaluation.report import main

raise SystemExit(run_main(main, user_errors=(FileNotFoundError,)))
