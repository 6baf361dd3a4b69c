"""The floor every layer stands on: error types with one-line messages (:mod:`~gnsx.core.errors`), atomic
file writes (:mod:`~gnsx.core.atomic`), physical and format constants (:mod:`~gnsx.core.constants`), the run
state a long job leaves behind (heartbeats, interrupted runs: :mod:`~gnsx.core.runstate`), CPU thread and
allocator settings (:mod:`~gnsx.core.threads`, :mod:`~gnsx.core.allocator`) and the command-line helpers every
tool shares (:mod:`~gnsx.core.cli`). Nothing here imports another gnsx package."""
