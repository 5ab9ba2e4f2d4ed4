"""The design study of the reconfigurable-Delta paper (``python -m eval.design``).

- :mod:`eval.design.model`: the design model every figure is judged by (rod forearms, scaled masses, the motor
  datasheet) and its cycles' conventions;
- :mod:`eval.design.performance`: the figures of merit of one geometry (workspace, torque on the 3.8 kg
  standard cycles, picks per minute with its own drive, speed at a joint-speed limit, peak-torque maps);
- :mod:`eval.design.codesign`: the catalogue drive of each geometry with the most picks per minute (one
  drive's pick rate: :mod:`eval.design.drive_rate`; the cheap path of the optimizer: :mod:`eval.design.screening`);
- :mod:`eval.design.optimize`: the pymoo problems (NSGA-II Pareto front, GA on the weighted cost);
- :mod:`eval.design.front`: NSGA-II on several seeds and the GA, every archive merged into one front;
- :mod:`eval.design.robustness`: the chosen designs' length tolerances and mass sensitivity;
- :mod:`eval.design.stiffness`: the platform's first natural frequency;
- :mod:`eval.design.drive_modes`: the first mode of each design's compliant drives over the task region;
- :mod:`eval.design.mechanism`: the paper's pitch-screw linkage, screw travel -> base radius and motor height;
- :mod:`eval.design.reconfigure`: the best screw setting per task profile, against the best fixed one;
- :mod:`eval.design.verify`: closed-loop verification on each design's own MuJoCo plant (the only module
  here that calls identification, the tare and the experiment engine's episodes);
- :mod:`eval.design.report`, :mod:`eval.design.profiles`, :mod:`eval.design.explorer`: tables, figures (the
  paper's Figs. 3-6 among them) and the interactive Pareto explorer page.

The kinematic analysis itself is :mod:`delta_env.workspace`; the mass rule is :mod:`delta_env.scaling`.
"""
