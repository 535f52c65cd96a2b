"""Options of the robust reconstruction: one frozen, checked :class:`RobustConfig`.

:func:`elphel_host.mfsr.robust.reconstruct` takes them; :data:`DEFAULT_CONFIG` is what it
uses when given none.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from elphel_host.mfsr.psf_spec import EstimateBlur, PsfSpec


@dataclass(frozen=True)
class RobustConfig:
    """Options of the robust reconstruction.

    Parameters
    ----------
    passes
        Robust passes after the first least-squares solve (each refines shifts and clips
        outliers).
    huber
        Residuals beyond this many noise sigmas are clipped.
    tau
        Expected HR gradient standard deviation as a fraction of the image's range; a
        smaller value smooths more.
    pad
        Mirror padding in LR px around each frame.
    refine
        Refine shifts against the model in the robust passes.
    refine_window
        Frames larger than this (px) have their shifts refined on a central window of
        this size, which costs a fraction of refining on the whole frame.
    noise_sigma
        Noise standard deviation in input units; None estimates it from the data.
    fit_noise
        Estimate the noise from the residuals of a weakly regularised fit of the burst
        (:func:`~elphel_host.mfsr.solve.fit_noise`) when there are enough frames; False:
        from the reference frame alone (:func:`~elphel_host.mfsr.frames.estimate_noise`),
        which reads fine texture as noise.
    psf
        What the optics are (:data:`~elphel_host.mfsr.psf_spec.PsfSpec`): estimated from
        the burst (the default), none, or given.
    choose_tau
        With a given PSF: cross-validate the prior's tau on the burst, the optics fixed
        (:func:`~elphel_host.mfsr.psf.cross_validated_tau`); False: ``tau`` as it is.
        An estimated PSF always comes with its tau; ``NoBlur`` keeps ``tau``.
    """

    passes: int = 1
    huber: float = 3.0
    tau: float = 0.04
    pad: int = 16
    refine: bool = True
    refine_window: int = 384
    noise_sigma: float | None = None
    fit_noise: bool = True
    psf: PsfSpec = field(default_factory=EstimateBlur)
    choose_tau: bool = True

    def __post_init__(self) -> None:
        if self.passes < 0:
            raise ValueError(f"passes={self.passes}; allowed: >= 0")
        if not self.huber > 0:
            raise ValueError(f"huber={self.huber}; allowed: > 0")
        if not self.tau > 0:
            raise ValueError(f"tau={self.tau}; allowed: > 0")
        if self.pad < 0:
            raise ValueError(f"pad={self.pad}; allowed: >= 0")
        if self.refine_window < 32:
            raise ValueError(f"refine_window={self.refine_window}; allowed: >= 32")


DEFAULT_CONFIG = RobustConfig()
