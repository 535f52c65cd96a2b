"""Multi-frame super-resolution of translated bursts.

* :mod:`~elphel_host.mfsr.registration` - validated ECC translation registration.
* :mod:`~elphel_host.mfsr.baseline` - the published direct method (bicubic, ECC, median).
* :mod:`~elphel_host.mfsr.forward`, :mod:`~elphel_host.mfsr.solve` - forward-model
  reconstruction solved exactly in the Fourier domain, with Huber outlier rejection;
  :mod:`~elphel_host.mfsr.ldl` - its batched block solve;
  :mod:`~elphel_host.mfsr.refine` - the robust pass's step per frame;
  :mod:`~elphel_host.mfsr.robust` - the PSF resolved, the noise, the shifts, the solve;
  :mod:`~elphel_host.mfsr.robust_config` - its options;
  :mod:`~elphel_host.mfsr.psf_spec` - what the optics are said to be (none, estimate,
  given), :mod:`~elphel_host.mfsr.gaussian_psf` - the one Gaussian PSF type,
  :mod:`~elphel_host.mfsr.psf` - the lens blur estimated from the burst,
  :mod:`~elphel_host.mfsr.psf_tp` - a quad calibration's PSFs;
  :mod:`~elphel_host.mfsr.robust_fuse` - one PSF, mono or Bayer;
  :mod:`~elphel_host.mfsr.regions` - a given PSF per image region, cells blended.
* :mod:`~elphel_host.mfsr.fuse` - burst in, image out (registration, then a method).
* :mod:`~elphel_host.mfsr.bayer` - Bayer sites, colour planes, luminance, demosaic.
* :mod:`~elphel_host.mfsr.stream` - the same fusion fed frame by frame while a burst is
  captured (``elphel burst capture --fuse``).
* :mod:`~elphel_host.mfsr.output` - the fused TIFF and its preview, written atomically.
* :mod:`~elphel_host.mfsr.frames` - frame checks, central windows, alignment, padding, noise.
* :mod:`~elphel_host.mfsr.scale` - the up-sampling factor's allowed range and its check.
* :mod:`~elphel_host.mfsr.metrics` - PSNR, SSIM; :mod:`~elphel_host.mfsr.synth` - test bursts.
"""
