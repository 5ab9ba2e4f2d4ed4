"""What the worker server runs once, before it forks the workers of every pool (:data:`eval.processes.WORKER_MODULES`).

Importing this module imports what every worker of the experiments needs (:mod:`eval.work` and
:mod:`eval.identification.run`: MuJoCo, the env, the controllers, filterpy, numba) and loads numba's compiler context
by running one cached kernel: numba sets that context up once per process, at the first compiled call, and a fork
inherits it instead of setting it up again in every worker. It first makes its process ignore SIGINT (Ctrl-C is the
command line's): import it in the worker server only.
"""

from __future__ import annotations

import importlib

from eval.processes import ignore_interrupts

# In the worker server as it imports (a Ctrl-C now would print its traceback) and in every worker it forks, which
# inherit the handler: the command line handles the interrupt (eval.processes.ignore_interrupts).
ignore_interrupts()

from controllers.monitor.compiled import loop_output  # noqa: E402

for module in ("eval.work", "eval.identification.run"):
    importlib.import_module(module)
loop_output(0.0, 0.0, 0.0, 0.0, 0.0)
