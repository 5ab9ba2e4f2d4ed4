"""Sweeps: a grid of scenarios x controllers x seeds, run on a local process pool or on Ray.

``python -m eval.sweep`` (see ``eval/sweep/__main__.py``); the work unit is :mod:`eval.sweep.work`, the
backends, results table and resume are :mod:`eval.sweep.runner`, summary and plots :mod:`eval.sweep.report`.
"""
