"""``python -m eval``: the controller comparison (:mod:`eval.comparison`), the project's main job."""

from eval.comparison.__main__ import main

if __name__ == "__main__":
    raise SystemExit(main())
