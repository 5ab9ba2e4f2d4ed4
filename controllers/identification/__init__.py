"""Offline identification of MId, MId+F and MId+F+R from recorded joint motion (docs/design.md section 7).

The algorithms, on samples of encoder angles and measured motor torques (the experiment that records them
is ``eval.identification.run``, its excitation runs ``eval.identification.excitation``):

- :mod:`~controllers.identification.data`: smoothed motion aligned with the torque samples (:class:`MotionData`);
- :mod:`~controllers.identification.paper`: the paper's method, replicated (grid search of rho1, rho2 per
  trajectory, then per-joint friction least squares, averaged);
- :mod:`~controllers.identification.least_squares`: ours, one joint least squares of all parameters, on the
  paper's lumped model or the model with rod forearms (MId+F+R);
- :mod:`~controllers.identification.stribeck`: the Stribeck excess near zero speed, fitted on the rows the least
  squares leaves out (the joints' breakaway torque);
- :mod:`~controllers.identification.compliance`: compliant drives' rotor inertia, gearhead stiffness, damping and
  backlash from a periodic excitation at rest poses with the load-side angle;
- :mod:`~controllers.identification.parameter_file`: the JSON parameter file with provenance;
- :mod:`~controllers.identification.logs`: the drive log files (CSV or Parquet) a robot's logger records;
- :mod:`~controllers.identification.bags`: ROS 2 bags (MCAP, sqlite3) of a robot's joint states as drive logs.
"""

from controllers.identification.compliance import (
    COMPLIANCE_PARAMETER_NAMES,
    ComplianceFit,
    fit_compliance,
    fit_motor_side_compliance,
)
from controllers.identification.data import (
    REST_VELOCITY,
    TRIM_SAMPLES,
    MotionData,
    concatenate,
    error_table,
    motion_at_torque_samples,
    prepare_motion,
    torque_errors,
)
from controllers.identification.least_squares import (
    FRICTION_VELOCITY_THRESHOLD,
    JOINT_PARAMETER_NAMES,
    LeastSquaresFit,
    between_trajectory_spread,
    fit_joint_least_squares,
    fit_least_squares,
    fit_rho_least_squares,
)
from controllers.identification.log_files import read_log, write_log
from controllers.identification.logs import (
    BAG_SUFFIXES,
    LOG_COLUMNS,
    MAX_LOG_GAP,
    DriveLog,
    LogFileError,
    resample_log,
)
from controllers.identification.paper import (
    RHO1_GRID,
    RHO2_GRID,
    PaperFit,
    fit_friction_per_joint,
    fit_paper_method,
    grid_search_rho,
    rho_grid,
)
from controllers.identification.parameter_file import (
    FILE_FORMAT_VERSION,
    MODEL_FIELDS,
    IdentificationResult,
    ParameterFileError,
    load_result,
    older_format,
    save_result,
)
from controllers.identification.stribeck import StribeckFit, fit_stribeck

__all__ = [
    "BAG_SUFFIXES",
    "COMPLIANCE_PARAMETER_NAMES",
    "FILE_FORMAT_VERSION",
    "FRICTION_VELOCITY_THRESHOLD",
    "JOINT_PARAMETER_NAMES",
    "LOG_COLUMNS",
    "MAX_LOG_GAP",
    "MODEL_FIELDS",
    "REST_VELOCITY",
    "RHO1_GRID",
    "RHO2_GRID",
    "TRIM_SAMPLES",
    "ComplianceFit",
    "DriveLog",
    "IdentificationResult",
    "LeastSquaresFit",
    "LogFileError",
    "MotionData",
    "PaperFit",
    "ParameterFileError",
    "StribeckFit",
    "between_trajectory_spread",
    "concatenate",
    "error_table",
    "fit_compliance",
    "fit_friction_per_joint",
    "fit_joint_least_squares",
    "fit_least_squares",
    "fit_motor_side_compliance",
    "fit_paper_method",
    "fit_rho_least_squares",
    "fit_stribeck",
    "grid_search_rho",
    "load_result",
    "motion_at_torque_samples",
    "older_format",
    "prepare_motion",
    "read_log",
    "resample_log",
    "rho_grid",
    "save_result",
    "torque_errors",
    "write_log",
]
