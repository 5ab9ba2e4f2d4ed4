"""Sweeps: a grid of scenarios x controllers x seeds, run on a local process pool or on Ray.

``python -m eval.sweep`` (see ``eval/sweep/__main__.py``), on top of the experiment engine: the work unit and its
runner are :mod:`eval.work`, the backends :func:`eval.processes.run_jobs`; a unit's row is :mod:`eval.sweep.work`,
the results table and resume :mod:`eval.sweep.runner`, summary and plots :mod:`eval.sweep.report`.
"""
