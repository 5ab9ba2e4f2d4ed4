"""The identification of a robot, ``python -m eval.identification``: excitation runs or drive logs, the
least squares, the report and the parameter files kept by robot identity."""
