"""The fault monitor's state and its step: one record (:data:`MONITOR`) that holds everything the monitor remembers,
and one compiled call per sample (:func:`monitor_step`) that runs every check on it (docs/design.md section 6,
"Fault monitor")."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.monitor.model_check import COLLIDED, MODEL_CHECK_FIELDS, SLIPPED, check_sample
from controllers.monitor.sensor_check import SENSOR_FIELDS, clean_encoders, clean_torques, record_event
from controllers.monitor.tuning import RESYNC_QUIET, SENSOR_QUIET
from delta_env.faults import FAULT_KINDS

EVENT_CAPACITY = 20
"""Detections one sample can make: three kinds per encoder and per torque reading, a slip and a collision."""

MONITOR = np.dtype(
    (
        np.record,
        [
            # the sample: its index since the reset, its reference's angles, rates and accelerations (rad, rad/s,
            # rad/s^2), its clean angles, rates and torques (rad, rad/s, N m)
            ("sample", np.int64),
            ("reference", np.float64, (3, 3)),
            ("clean", np.float64, (3, 3)),
            # what the sample says (FaultMonitor's attributes of the same names)
            ("faulty", np.bool_),
            ("suspect", np.bool_),
            ("resynced", np.bool_),
            ("slipped", np.bool_),
            ("quiet_samples", np.int64),
            # what it detected: kind (index in FAULT_KINDS), joint (-1 for none), magnitude
            ("event_count", np.int64),
            ("event_kind", np.int64, (EVENT_CAPACITY,)),
            ("event_joint", np.int64, (EVENT_CAPACITY,)),
            ("event_magnitude", np.float64, (EVENT_CAPACITY,)),
            # faulty samples in a row, and the last sample whose reading the model's equations leave out
            ("faulty_run", np.int64),
            ("quiet_until", np.int64),
            *SENSOR_FIELDS,
            *MODEL_CHECK_FIELDS,
        ],
    )
)
"""Everything a :class:`~controllers.monitor.FaultMonitor` remembers: the sensor checks'
(:data:`~controllers.monitor.sensor_check.SENSOR_FIELDS`) and the model checks' state
(:data:`~controllers.monitor.model_check.MODEL_CHECK_FIELDS`), and the last sample's."""

SLIP, COLLISION = FAULT_KINDS.index("slip"), FAULT_KINDS.index("collision")
"""Codes of the kinds the model checks detect: their indices in :data:`~delta_env.faults.FAULT_KINDS`."""

DETECTED = 8
"""Bit of :func:`monitor_step`'s result: the sample made detections (the record's events)."""

BAD_SHAPE = -1
""":func:`monitor_step`'s result for readings that are not three-vectors: nothing was changed."""


@numba.njit(cache=True)
def monitor_step(
    state_bytes: NDArray[np.uint8],
    model_constants: NDArray[np.uint8],
    angles: NDArray[np.float64],
    rates: NDArray[np.float64],
    torques: NDArray[np.float64],
    reference_angles: NDArray[np.float64],
    reference_rates: NDArray[np.float64],
    reference_accelerations: NDArray[np.float64],
    command: NDArray[np.float64],
    has_command: bool,
    holding: bool,
    arm_angles: NDArray[np.float64],
    has_arm: bool,
) -> int:
    """One sample into the :data:`MONITOR` record ``state_bytes`` (its bytes, in place): the encoder readings (rad)
    and rates (rad/s), the measured torques (N m), the reference, the command (N m) sent after the last sample
    (``has_command`` False at the first), the gripper, and the arm encoders' readings (rad) of compliant drives
    (``has_arm`` False: none; the encoders read the arms). Runs the sensor checks, then the model checks on the
    clean readings, the arms' angles where an arm encoder reads them (with the model's constants of
    :class:`~controllers.dynamics.DeltaDynamics`); the clean readings are the record's ``clean`` rows, this sample's
    detections its events. Returns the bits of the rows that differ from the readings
    (:data:`~controllers.monitor.sensor_check.ANGLES_REPLACED`, ``RATES_REPLACED``, ``TORQUES_REPLACED``) and
    :data:`DETECTED`, or :data:`BAD_SHAPE`."""
    if (
        angles.shape[0] != 3
        or arm_angles.shape[0] != 3
        or rates.shape[0] != 3
        or torques.shape[0] != 3
        or reference_angles.shape[0] != 3
        or reference_rates.shape[0] != 3
        or reference_accelerations.shape[0] != 3
        or command.shape[0] != 3
    ):
        return BAD_SHAPE
    state = state_bytes.view(MONITOR)[0]
    state.sample += 1
    state.event_count = 0
    state.resynced = state.slipped = False
    state.reference[0, :] = reference_angles
    state.reference[1, :] = reference_rates
    state.reference[2, :] = reference_accelerations
    replaced = clean_encoders(state, angles, rates, model_constants)
    replaced |= clean_torques(state, torques, command, has_command)
    faulty = suspect = short = stepped_back = False
    for joint in range(3):
        faulty |= state.encoder_bad[joint] != 0 or state.torque_bad[joint] > 0
        faulty |= state.nan_active[joint] != 0 or state.nan_active[3 + joint] != 0
        suspect |= state.stuck[joint] > 0
        short |= state.short_run[joint] > 0
        stepped_back |= state.delivering[joint] == 1
    state.faulty, state.suspect = faulty, suspect
    state.faulty_run = state.faulty_run + 1 if faulty else 0
    # A lone replaced reading is as good as the reading (the reference plus the tracking error a millisecond ago, or
    # the current loop's prediction): the model's equations keep it. Replacements in a row drift from the joint (a
    # stuck encoder: the joint runs on its feedforward), so they and the smoother's lag after them are left out, and
    # the smoother's window after a step back: of the clean readings onto an encoder, or of a drive's torque onto its
    # command when a drive fault ends (its joint's acceleration steps with it, which the smoother spreads over its
    # window). A suspect repeated reading is a replaced one like any other: a push that stops a moving joint repeats
    # its reading once, and leaving the window out from that first repeat on hid the push for 26 samples; a stuck
    # encoder's second repeat is a replacement in a row.
    # a step back: onto the encoder, or of a faulty drive's torque onto its command (from its first delivering reading)
    if state.resynced or stepped_back or state.drive_ended:
        state.quiet_samples = RESYNC_QUIET
    elif state.faulty_run > 1:
        state.quiet_samples = SENSOR_QUIET
    elif short:  # maybe a drive's loss: the command's prediction is not what the joint got
        state.quiet_samples = 1
    else:
        state.quiet_samples = 0
    if state.quiet_samples:
        state.quiet_until = max(state.quiet_until, state.sample + state.quiet_samples)
    # On compliant drives the motor encoders read the rotors, which the gearheads' twist puts off the arms by the
    # arm's torque over the stiffness: the model's arm moves with the arm encoders (docs/design.md section 6).
    checked_angles = arm_angles if has_arm else state.clean[0]
    found = check_sample(state, model_constants, checked_angles, holding, state.sample <= state.quiet_until)
    if found & SLIPPED:
        record_event(state, SLIP, -1, state.slip_mass)
        state.slipped = True
    if found & COLLIDED:
        record_event(state, COLLISION, -1, state.force_magnitude)
    return replaced | (DETECTED if state.event_count else 0)
