"""The fit of the model's corrections on the empty moves: weighted least squares with a Gaussian prior
(docs/design.md section 6; the package docstring gives the physics)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from controllers.payload.equation import ARM_MASS_SCALE, FIT, FRICTION_SCALE, PARAMETERS, PLATFORM_MASS, solve_fit
from delta_env.validation import require_positive


class ModelCorrections(NamedTuple):
    """Corrections of the identified model to the robot at hand, fitted on the empty moves of an episode.

    The plant's torque with an empty gripper is modelled as tau0 + dm phi + d_arm (I thdd + G) + kappa_i f_i: the
    model's, plus what mass and friction errors add (the model is linear in each; docs/design.md section 3).

    Attributes:
        platform_mass: dm (kg), the mass the model lacks at the platform: a payload-like offset along phi.
        arm_mass_scale: d_arm, the relative error of the arms' inertia I = (m1/3 + m2) l1^2 and gravity amplitude
            G = -(m1/2 + m2) g l1 together (dimensionless; :data:`MASS_CORRECTION_STD`).
        friction_scale: kappa_i, the relative error of each joint's friction fv_i thd_i + fc_i sign(thd_i), (3,).
    """

    platform_mass: float
    arm_mass_scale: float
    friction_scale: NDArray[np.float64]


class EmptyMoveSums(NamedTuple):
    """The weighted least-squares sums of a robot's empty moves, over the columns of :class:`ModelCorrections`
    (platform mass, arm-mass scale, three friction scales).

    What the robot's earlier work taught about its own mass and friction errors: seeded into the fit at every
    episode (``PayloadEstimator(empty_moves=...)``), they make its corrections as certain from the start as many
    empty moves would. Only for the robot they were measured on.

    Attributes:
        information: sum of w c c^T, (5, 5).
        moment: sum of w c y, (5,).
    """

    information: NDArray[np.float64]
    moment: NDArray[np.float64]


def _checked_sums(sums: EmptyMoveSums) -> EmptyMoveSums:
    """``sums`` as float arrays of shapes (5, 5) and (5,), finite, the information symmetric; else ValueError."""
    information = np.array(sums.information, dtype=np.float64)
    moment = np.array(sums.moment, dtype=np.float64)
    if information.shape != (PARAMETERS, PARAMETERS) or moment.shape != (PARAMETERS,):
        raise ValueError(f"empty_moves must be (5, 5) and (5,) sums, got shapes {information.shape} and {moment.shape}")
    if not (np.all(np.isfinite(information)) and np.all(np.isfinite(moment))):
        raise ValueError("empty_moves must be finite")
    if not np.allclose(information, information.T, rtol=1e-9, atol=0.0):
        raise ValueError("empty_moves.information must be symmetric (a sum of w c c^T)")
    return EmptyMoveSums(information, moment)


class CorrectionFit:
    """Weighted least squares of the model's corrections p (:class:`ModelCorrections`) on the empty moves, with a
    zero-mean Gaussian prior: p = (A + P0^-1)^-1 b with A = sum w c c^T and b = sum w c y over the samples.

    The payload equation's kernels (:mod:`controllers.payload.equation`) add the empty-move samples to its record and
    solve it at the first carrying sample after them; the carries use that solution until the next carry.

    Args:
        mass_correction_std: Prior standard deviations of the platform-mass error (kg) and of the arms' relative
            mass error (dimensionless); None holds both at 0 (not fitted).
        friction_scale_std: Prior standard deviation of each joint's friction scale error (dimensionless); None
            holds them at 0.
        seed: Sums of the robot's earlier empty moves that every episode starts from, or None (the prior alone).
            Needs a fitted parameter.

    Attributes:
        state: The bytes of its :data:`~controllers.payload.equation.FIT` record, which the kernels update in place.
        seed: The checked seed sums, or None.
    """

    def __init__(
        self,
        mass_correction_std: tuple[float, float] | None,
        friction_scale_std: float | None,
        seed: EmptyMoveSums | None = None,
    ) -> None:
        if friction_scale_std is not None:
            require_positive("friction_scale_std", friction_scale_std)
        if mass_correction_std is not None:
            if len(mass_correction_std) != 2:
                raise ValueError(f"mass_correction_std must be 2 values (kg, -), got {mass_correction_std!r}")
            for name, std in zip(("platform mass", "arm mass scale"), mass_correction_std, strict=True):
                require_positive(f"mass_correction_std ({name})", std)
        # prior information 1 / std^2 of the parameters (columns PLATFORM_MASS, ARM_MASS_SCALE, FRICTION_SCALE...):
        # infinite for those held at 0
        prior = np.empty(PARAMETERS)
        prior[:FRICTION_SCALE] = math.inf if mass_correction_std is None else [std**-2 for std in mass_correction_std]
        prior[FRICTION_SCALE:] = math.inf if friction_scale_std is None else friction_scale_std**-2
        self._prior = prior
        self._record = np.zeros(1, FIT)
        self.state = self._record.view(np.uint8)
        self._fields = self._record[0]
        self._solution = self._fields["solution"]
        self.seed = None if seed is None else _checked_sums(seed)
        if self.seed is not None and not self.fits:
            raise ValueError("empty_moves seed the fit of the model's corrections, but this estimator fits none")
        self.restart()

    @property
    def fits(self) -> bool:
        """Whether any correction is fitted (a finite prior information)."""
        return not np.all(np.isinf(self._prior))

    def restart(self) -> None:
        """The fit as an episode starts: the seeded sums, to be solved at the first carry, or nothing."""
        self._record[:] = 0  # every field
        fields = self._fields
        fields["prior_information"], fields["fits"] = self._prior, self.fits
        if self.seed is not None:
            fields["information"], fields["moment"] = self.seed.information, self.seed.moment
            fields["stale"] = True

    @property
    def platform_mass(self) -> float:
        """dm (kg) as solved at the last carry's start: what the feedforward adds to the payload estimate."""
        return self._solution.item(PLATFORM_MASS)

    @property
    def corrections(self) -> ModelCorrections:
        """The corrections fitted on the seed and this episode's empty moves so far (0 before any).

        Solved on a copy: the solution the carries and the feedforward use stays the one of the last carry's start.
        """
        record = self._record
        if record["stale"][0]:
            record = record.copy()
            solve_fit(record.view(np.uint8))
        p = record["solution"][0]
        return ModelCorrections(float(p[PLATFORM_MASS]), float(p[ARM_MASS_SCALE]), p[FRICTION_SCALE:].copy())

    @property
    def sums(self) -> EmptyMoveSums:
        """The sums so far (:class:`EmptyMoveSums`): the seed plus this episode's empty moves."""
        return EmptyMoveSums(self._fields["information"].copy(), self._fields["moment"].copy())

    @property
    def samples(self) -> int:
        """Samples of this episode's empty moves that entered the fit so far."""
        return int(self._fields["samples"])
