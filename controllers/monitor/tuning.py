"""The fault monitor's settings, each with its reason: its detection thresholds and the reactions of a monitored
controller (docs/design.md section 6, "Fault monitor")."""

from __future__ import annotations

from controllers.estimation import SMOOTHER_HISTORY, SMOOTHER_JERK_STD, SMOOTHER_LAG, SMOOTHER_WINDOW
from controllers.identification.least_squares import FRICTION_VELOCITY_THRESHOLD

ACCELERATION_FACTOR = 2.0
"""An encoder step is implausible when its second difference asks more than this many times the acceleration the
joint's own drive gives its arm at peak torque (peak / (rho1 I)): the other chains and an external force can add
to it, but not double it (a 1000 N push on the platform adds about 300 N m at a joint)."""

STUCK_COUNTS = 4.0
"""An encoder that repeats its reading is suspect when the step its joint was to make (its last step plus its last
second difference) and its reference's step were at least this many counts; a joint that left rest is stuck only
while its reference runs this many counts per sample."""

STUCK_SAMPLES = 3
"""Repeated readings of a suspect encoder that make it stuck."""

TURN_HISTORY = 4
"""Readings before a run of repeats from which the stuck check bounds the joint's speed where its reading stopped
changing (docs/design.md section 6, "Encoders", case (c)): going back m samples narrows the count's share of the
bound, q / (m T), while the acceleration's share, about its bounds' width times m T / 2, grows; with the width of
4 b_i / S_i (b_i the breakaway, S_i the joint's inertia; its size on the campaigns' reversals is in
docs/measurements.md) the two meet at about two samples. Each m adds a bound (the speed lies within all of them),
so going further costs only one model evaluation per sample once per run of repeats."""

TORQUE_MARGIN = 6.0
"""How far (N m) a measured torque may lie outside the span of the last torque and the commands held since (the one
before the last command still drove the loop for the reading's age): the sensor's noise (0.5 N m, so about 8
standard deviations of a difference of two readings) with room."""

DRIVE_FAULT_SAMPLES = 3
"""Consecutive implausible torques of one joint, all short of the prediction, that make a drive fault rather than a
sensor glitch."""

SLOWEST_LAG_FACTOR = 2.5
"""The slowest current loop the monitor takes for healthy: this many times the identified time constant (a drive
whose loop slowed from 1 to 2.5 ms is worn, not faulty)."""

DRIVE_FAULT_DRIFT = 2.0
"""Shortfall (N m) per sample below the slowest healthy loop's step that the CUSUM forgives: the measured torque's
noise (0.5 N m on each of two readings) with room."""

DRIVE_FAULT_STEP = 8.0
"""Largest shortfall (N m) one sample adds to the CUSUM, so that one odd reading cannot make a drive fault."""

DRIVE_FAULT_EVIDENCE = 20.0
"""Accumulated shortfall beyond the drift (N m, summed over samples) that makes a drive fault: at least four
samples that each fall short by more than 7 N m. Also the threshold of the window's excess
(:data:`DRIVE_FAULT_WINDOW`), in the same unit."""

DRIVE_FAULT_WINDOW = 16
"""Readings over which the current loop's integral identity is checked (docs/design.md section 6, "Torques"): the
command less the measured torque, summed over them, is what any first-order loop with a lag up to the slowest healthy
one owes for its output's change; a drive that holds its torque short of the command gathers the shortfall on every
reading. The sum's noise is the readings' (0.5 N m each: 2 N m over 16, and as much again from the output's change
the identity takes off, which the slowest loop scales by 3), a sixth of :data:`DRIVE_FAULT_EVIDENCE`; a shortfall of
1.25 N m held over the window reaches it, a few N m within a few samples. A longer window would find smaller losses
and take more of a slow loop's transients; on fault-free work at 3-15 g, the time-optimal timings and 10 kg, the
excess stayed at 7.2 N m at most on the rows measured (docs/measurements.md)."""

FORCE_REFERENCE = 60.0
"""Platform force (N) the collision CUSUM forgives per sample: above the model's residual on healthy work, the
fastest timings and the residual policy's torque steps included (measured in docs/measurements.md, "Faults")."""

REST_FORCE_REFERENCE = 40.0
"""Platform force (N) the collision CUSUM forgives per sample where nothing moves: the checked sample's reference
still (no planned rate or acceleration), every joint slower than :data:`REST_RATE`, and no place within the
smoothing window (the arm springs back from the weight its drives held). There the model's errors of motion that
:data:`FORCE_REFERENCE` covers (inertia, the smoother's acceleration error at the motion's steps) are nil and the
joints' unknown friction has its own allowance, so what is left is the gravity model's error and the torque sensor's
noise, a fraction of this (docs/measurements.md, "Pushes just after the grip"). A push on a resting arm shows in the
residual only as fast as the smoother shows the acceleration it causes, so the lower drift gathers its evidence
sooner (docs/design.md section 6, "Fault monitor")."""

FORCE_EVIDENCE = 60.0
"""Accumulated force beyond the drift (:data:`FORCE_REFERENCE`, or :data:`REST_FORCE_REFERENCE` where nothing moves;
N, summed over samples) that makes a collision: on a moving arm one sample of 120 N or two of 90 N, at rest one of
100 N or two of 70 N."""

PLANT_STEP_LAG = 2
"""Samples within which the plant's acceleration follows a step of the reference's: the current loop's time constant
(0.5-2 ms on the ``randomized`` plants, about one sample after the lag row's lead). The collision check's band
allows for the smoother's error with any of these lags (docs/design.md section 6, "Fault monitor")."""

BREAKAWAY_FACTOR = 1.5
"""Breakaway (static) friction of a joint as a multiple of its Coulomb friction fc: the torque its friction can
hold at rest. An assumption, not an identified value: the identification leaves rows at rest out
(:mod:`controllers.identification.least_squares`), so nothing measures it; 1.5 fc is a usual upper figure for
geared servo joints, and the simulated plant's Stribeck excess (+50 % of Coulomb) reaches it."""

REST_RATE = FRICTION_VELOCITY_THRESHOLD
"""Speed (rad/s) below which the collision check takes a joint's friction for unknown within +-:data:`BREAKAWAY_FACTOR`
fc instead of the model's fc sign(theta_dot): the identification's bound of the rate model's validity (0.2 rad/s,
where the Stribeck excess has decayed). At a stop, the smoothed rate's sign says little, and a joint that sticks
holds any torque up to its breakaway: at 3 g this friction made most of the healthy residual's force
(docs/measurements.md, "Faults"). A slow joint whose readings move slides, and its friction only resists the
motion: within [0, b] on the motion's side (docs/design.md section 6, "Fault monitor")."""

SLIP_MIN_MASS = 0.3
"""Lightest mass held (kg) whose loss the consistency check looks for, asked of the mass's upper confidence bound
(:data:`SLIP_MASS_CONFIDENCE`); below, the torque noise hides it."""

SLIP_MASS_CONFIDENCE = 2.0
"""Standard errors of the mass held by which its estimate may fall short of :data:`SLIP_MIN_MASS` and the loss still
be looked for: the check starts once the upper confidence bound held + 2 sigma (one-sided 97.7 %) reaches it, so that
an object of the lightest mass is tested although its estimate, a random variable about its true mass, falls below
it about half the time (docs/design.md section 6, "Slips")."""

HELD_MASS_STD = 0.05
"""Standard error (kg) below which the mass held is taken out of the collision check's residual (before, the part
along phi that a mass the cup can hold explains is left out): 0.05 kg times phi is about 1 N m."""

SLIP_PRECISION = 0.1
"""The slip check starts once the standard error of the mass held is below this fraction of it: an early estimate
of a light object, biased by the static friction of the lift-off, would make "gone" and "held" hard to tell."""

SLIP_EVIDENCE = 12.0
"""Log-likelihood ratio (the CUSUM's threshold) at which "the object is gone" wins over "it is still held"."""

PUSH_SHOWN_SHARE = 0.875
"""Share of a step in the residual that the checked sample shows once a push's onset is over: 8 samples after the
step enters the smoother's window. The smoother spreads a push's onset over its window, and early on a push against
the object's weight looks like its loss, which for a heavy object is worth 24 per sample; so no sample adds more
than :data:`SLIP_EVIDENCE` over those 8 to the slip check's CUSUM, and a slip takes at least as long as the onset
to show, by when the push's force, which "gone" does not explain, has cleared the CUSUM (docs/design.md section 6,
"Fault monitor"). Heavy objects' slips are found a few ms later; light ones', whose samples add less, as before."""

INITIAL_RESIDUAL_STD = 4.0
"""Standard deviation (N m) of the model's residual the slip check assumes at a reset, before it has measured its
robot's: the identified model's error on a robot whose masses and friction differ from its identification by up to
10 and 30 % (the ``randomized`` preset), at 6 g."""

SCATTER_RATE = 0.01
"""Weight of each moving sample in the running mean square of the model's residual (a memory of about 100 samples),
from which the slip check takes the residual's variance, at least the payload estimator's 1.5 N m squared."""

SLIP_WINDOW = 2 * SMOOTHER_WINDOW
"""Longest run (samples) that the slip check's window statistic weighs with the residual's measured correlation:
the residual's correlation spans the smoother's window, so over twice that its sums' variance per unit of
information has settled (docs/design.md section 6, "Light slips: the residual's correlation"); longer runs are
the CUSUM's."""

CORRELATION_RATE = 0.002
"""Weight of each sample in the running means from which the slip check measures its residual's correlation (a
memory of about 500 samples, about 10 windows of :data:`SLIP_WINDOW` samples); the window statistic weighs a window
of n samples once n / (CORRELATION_RATE SLIP_WINDOW) samples have been learned after a reset, as many windows of its
length."""

SLIP_SETTLE = 0.03
"""Time after the pick (s) before the mass held is trusted as a reference."""

SENSOR_QUIET = SMOOTHER_HISTORY + SMOOTHER_LAG + 1
"""Readings whose model equations (the monitor's checks, the payload estimator's) are left out after replaced
readings in a row: the smoother's window, every smoothed state that leans on them."""

RESYNC_QUIET = SMOOTHER_HISTORY + 2 * SMOOTHER_LAG + 1
"""Readings kept out of the model's equations after the clean readings step back onto an encoder that was replaced
for a while (a stuck spell): the step sits in the smoother's whole window."""

MONITOR_JERK_STD = SMOOTHER_JERK_STD
"""Jerk standard deviation (rad/s^3) of the monitor's fixed-lag smoother of the tracking error (the clean angles less
the reference, whose own derivatives are added back): the offline smoother's, a third of the payload estimator's
(:data:`~controllers.estimation.FIXED_LAG_JERK_STD`). The residual force and the slip check sum evidence over many
samples, and the error's jerk is small next to the reference's, while the acceleration noise of a higher value
enters the force through the whole inertia; the monitor's thresholds were set, and its campaigns and soak measured,
with this value (docs/measurements.md, "Faults")."""

SLOW_RATE = 0.5
"""Speed override (of the reference's speed) a ``"slow"`` reaction (:data:`~delta_env.faults.FAULT_REACTIONS`)
asks for."""

ROLLBACK_SAMPLES = 20
"""How far back (samples beyond the monitor's lag) a detected collision can undo the payload estimator's updates: its
onset, which the check sees only in part for 8 samples (:data:`PUSH_SHOWN_SHARE`), and the samples its evidence took
to grow (1-5 on the campaigns' pushes), with room."""

REACTING_KINDS = ("collision", "slip", "drive_fault")
"""The detected faults a reaction answers; sensor faults are replaced and the work goes on."""
