"""The pick-rate data sheet, ``python -m eval.rate``: picks per minute on the standard cycle within the drive's
envelope, beside a published industrial robot's."""
