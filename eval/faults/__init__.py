"""The fault campaign, ``python -m eval.faults``: injected faults scored against what each controller detected, and
the false-alarm soak (``python -m eval.faults.soak``)."""
