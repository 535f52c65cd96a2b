"""``elphel mfsr``: fuse burst directories; ``elphel mfsr compare``: methods side by side.

* ``elphel mfsr BURST_DIR [BURST_DIR ...] --scale S [--method robust|baseline]
  --out OUT.tif [--float] [--json]`` writes the fused TIFF (16-bit DN, or float32) and a
  PNG preview next to it. With several burst directories ``--out`` is a directory, one
  ``<burst name>.tif`` each, and the bursts run in parallel on a Dask cluster (local by
  default, or ``--scheduler tcp://host:8786``), with progress on stderr as each finishes.
* ``elphel mfsr compare BURST_DIR --scale S [--reference REF.tif] --out DIR`` runs
  bicubic, baseline and robust, scores them against the reference (PSNR, SSIM) and writes
  the three TIFFs, a ``compare.json`` and a side-by-side crops PNG.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.burst.io import read_burst
from elphel_host.cli_common import add_json_option, emit
from elphel_host.errors import InputFormatError
from elphel_host.mfsr.fuse import FusionResult, fuse_burst
from elphel_host.mfsr.metrics import psnr, ssim
from elphel_host.mfsr.output import fused_meta, write_image
from elphel_host.mfsr.psf_given import parse_psf
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.scale import MAX_SCALE, MIN_SCALE
from elphel_host.preview import save_preview
from elphel_host.progress import ProgressLine

if TYPE_CHECKING:  # the quad's PSFs are imported when asked for (SciPy's optimiser)
    from elphel_host.burst.io import Burst
    from elphel_host.mfsr.psf_tp import QuadPsfs


def register(subparsers: Any) -> None:
    """Add the ``mfsr`` subcommand."""
    p = subparsers.add_parser(
        "mfsr",
        help="multi-frame super-resolution of burst directories (or: mfsr compare ...)",
        description="Fuse sub-pixel bursts (burst directories) into one image on the first frame's "
        "grid up-sampled by --scale. 'elphel mfsr compare BURST_DIR ...' compares bicubic, "
        "baseline and robust instead.",
    )
    p.add_argument(
        "burst_dirs",
        nargs="+",
        metavar="BURST_DIR",
        help="burst directories (or 'compare' followed by one burst directory)",
    )
    p.add_argument(
        "--scale", type=int, required=True, metavar="S", help=f"integer {MIN_SCALE}..{MAX_SCALE}"
    )
    p.add_argument(
        "--method",
        choices=("robust", "baseline"),
        default="robust",
        help="robust (default): forward-model reconstruction; baseline: "
        "bicubic + ECC + median, the published direct method",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="OUT",
        help="output TIFF (a directory with several bursts or with compare)",
    )
    p.add_argument("--float", action="store_true", help="write float32 instead of 16-bit DN")
    p.add_argument(
        "--psf",
        default=None,
        metavar="PSF",
        help="optics blur the robust method deconvolves: auto (default: estimated from the "
        "burst), none (the pixel aperture alone), sigma=S (a Gaussian of S output px), "
        "FILE.npy (a PSF on the output grid, odd sides up to 31; or 4-D, rows x columns "
        "of regions x the PSF: one PSF per image region) or quad=QUAD_DIR[,camera=N] (the "
        "PSFs behind the aberration-correction kernels of a tile-processor quad directory, "
        "one per kernel cell; the burst must cover that camera's whole image)",
    )
    p.add_argument(
        "--psf-regions",
        default=None,
        metavar="RxC",
        help="a PSF per image region: R rows x C columns of regions (1..8 each), each "
        "estimated from its own pixels and the results blended (default 1x1: one PSF)",
    )
    p.add_argument(
        "--blur-sigma",
        type=float,
        default=None,
        metavar="PX",
        help="the same as --psf sigma=PX",
    )
    p.add_argument(
        "--no-prior", action="store_true", help="ignore the stage/optics prior of the manifest"
    )
    p.add_argument(
        "--reference", metavar="REF.tif", help="compare: ground truth on the output grid"
    )
    p.add_argument(
        "--scheduler",
        metavar="URL",
        help="several bursts: Dask scheduler address (default: a local cluster)",
    )
    add_json_option(p)
    p.set_defaults(func=run)


def psf_regions(text: str | None) -> tuple[int, int]:
    """``--psf-regions RxC`` as (rows, columns); None: (1, 1)."""
    if text is None:
        return (1, 1)
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise InputFormatError(f"--psf-regions {text!r}; allowed: RxC, e.g. 2x3")
    return (int(parts[0]), int(parts[1]))


def robust_config(
    psf: str | None,
    blur_sigma: float | None = None,
    regions: str | None = None,
    *,
    scale: int | None = None,
) -> RobustConfig:
    """The robust method's options from ``--psf``, ``--blur-sigma`` and ``--psf-regions``.

    ``scale``: the output's, which a quad's PSFs (``--psf quad=DIR``) are drawn at, for
    frames that are the quad's whole images (`elphel_host.mfsr.psf_tp.burst_config` draws
    them for a burst's own window).
    """
    try:
        quad = quad_option(psf, blur_sigma, regions)
        if quad is not None:
            if scale is None:
                raise ValueError("--psf quad=DIR needs the output's scale")
            from elphel_host.mfsr.psf_tp import quad_config

            return quad_config(quad, scale)
        return replace(_psf_config(psf, blur_sigma), psf_regions=psf_regions(regions))
    except ValueError as e:
        raise InputFormatError(str(e)) from e


def quad_option(psf: str | None, blur_sigma: float | None, regions: str | None) -> QuadPsfs | None:
    """``--psf quad=DIR[,camera=N]``: the PSFs recovered from a quad's kernel file."""
    if psf is None or not psf.strip().startswith("quad="):
        return None
    from elphel_host.mfsr.psf_tp import quad_psfs

    if regions is not None:
        raise InputFormatError(
            f"--psf-regions {regions} and --psf {psf}: the quad's kernel grid sets "
            "the regions; give one of them"
        )
    if blur_sigma is not None:
        raise InputFormatError(f"--blur-sigma {blur_sigma} and --psf {psf}: give one of them")
    where, _, rest = psf.strip()[len("quad=") :].partition(",")
    camera = rest[len("camera=") :] if rest.startswith("camera=") else None
    if not where or (rest and (camera is None or not camera.isdigit())):
        raise InputFormatError(f"--psf {psf!r}; allowed: quad=QUAD_DIR or quad=QUAD_DIR,camera=N")
    return quad_psfs(where, int(camera or 0))


def _burst_config(
    config: RobustConfig, quad: QuadPsfs | None, burst_dir: str, burst: Burst, scale: int
) -> RobustConfig:
    if quad is None:
        return config
    from elphel_host.mfsr.psf_tp import burst_config

    return burst_config(quad, burst_dir, burst, scale)


def _psf_config(psf: str | None, blur_sigma: float | None) -> RobustConfig:
    if blur_sigma is not None:
        if psf is not None:
            raise InputFormatError(f"--blur-sigma {blur_sigma} and --psf {psf}: give one of them")
        psf = f"sigma={blur_sigma}"
    try:
        given = parse_psf(psf or "auto")
    except ValueError as e:
        raise InputFormatError(str(e)) from e
    if given is None:
        return RobustConfig(estimate_psf=True)
    if given.kernel is not None and given.kernel.ndim == 4:
        return RobustConfig(psf_grid=given.kernel)
    if given.kernel is not None:
        return RobustConfig(psf_kernel=given.kernel)
    # a given sigma: its prior's tau is still chosen (`none`: the pixel aperture alone, no search)
    return RobustConfig(blur_sigma=given.sigma, estimate_psf=given.sigma > 0)


def _fuse_one(
    burst_dir: str,
    scale: int,
    method: str,
    out: str,
    as_float: bool,
    config: RobustConfig,
    use_prior: bool,
    quad: QuadPsfs | None = None,
) -> dict[str, Any]:
    burst = read_burst(burst_dir)
    res = fuse_burst(
        burst,
        scale=scale,
        method=method,
        use_prior=use_prior,
        config=_burst_config(config, quad, burst_dir, burst, scale),
    )
    meta = fused_meta(method=method, scale=scale, burst=burst_dir, bayer=burst.bayer)
    written = write_image(Path(out), res.image, as_float=as_float, meta=meta)
    return {"burst": str(burst_dir), **written, **res.report()}


def run(args: argparse.Namespace) -> int:
    args.quad_psfs = quad_option(args.psf, args.blur_sigma, args.psf_regions)
    args.robust_config = (
        RobustConfig()  # the quad's PSFs are drawn per burst, under its window
        if args.quad_psfs is not None
        else robust_config(args.psf, args.blur_sigma, args.psf_regions, scale=args.scale)
    )
    if args.burst_dirs[0] == "compare":
        return run_compare(args)
    dirs = args.burst_dirs
    if len(dirs) == 1:
        result = _fuse_one(
            dirs[0],
            args.scale,
            args.method,
            args.out,
            args.float,
            args.robust_config,
            not args.no_prior,
            args.quad_psfs,
        )
        human = (
            f"{result['out']}: {result['method']} x{args.scale}, {result['used']}/"
            f"{result['frames']} frames, {result['seconds']:.2f} s"
            + (
                f"; excluded {[e['index'] for e in result['excluded']]}"
                if result["excluded"]
                else ""
            )
        )
        emit(args, result, human)
        return 0
    results = _run_many(args)
    emit(
        args,
        {"bursts": results},
        "\n".join(
            f"{r['out']}: {r['used']}/{r['frames']} frames, {r['seconds']:.2f} s" for r in results
        ),
    )
    return 0


def _run_many(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Fuse each burst directory on a Dask cluster; results in the order given.

    Progress (one step per burst, as each finishes) goes to stderr.
    """
    try:
        from dask.distributed import as_completed
    except ImportError as e:
        raise InputFormatError(
            "several burst directories need dask[distributed] (pip install 'dask[distributed]'); "
            "or fuse one directory per call"
        ) from e
    from elphel_host.parallel import dask_client

    out_dir = Path(args.out)
    names = [Path(d).resolve().name for d in args.burst_dirs]
    if len(set(names)) != len(names):
        raise InputFormatError(
            f"burst directory names {names}; allowed: distinct names "
            "(each becomes <name>.tif in --out)"
        )
    outs = [str(out_dir / f"{n}.tif") for n in names]
    total = len(outs)
    results: list[dict[str, Any] | None] = [None] * total
    line = ProgressLine()
    line.update(f"mfsr: 0/{total} bursts fused", done=0, total=total)
    try:
        with dask_client(args.scheduler) as client:
            futures = {
                client.submit(
                    _fuse_one,
                    d,
                    args.scale,
                    args.method,
                    o,
                    args.float,
                    args.robust_config,
                    not args.no_prior,
                    args.quad_psfs,
                    pure=False,
                ): i
                for i, (d, o) in enumerate(zip(args.burst_dirs, outs, strict=True))
            }
            for done, future in enumerate(as_completed(futures), start=1):
                i = futures[future]
                results[i] = future.result()
                line.update(
                    f"mfsr: {done}/{total} bursts fused (last: {names[i]})", done=done, total=total
                )
    finally:
        line.end()
    return [r for r in results if r is not None]


def _crop(image: NDArray[np.float32], size: int) -> NDArray[np.float32]:
    h, w = image.shape[:2]
    y0, x0 = max(0, (h - size) // 2), max(0, (w - size) // 2)
    return image[y0 : y0 + size, x0 : x0 + size]


def run_compare(args: argparse.Namespace) -> int:
    if len(args.burst_dirs) != 2:
        raise InputFormatError(f"compare takes one BURST_DIR, got {args.burst_dirs[1:]}")
    burst = read_burst(args.burst_dirs[1])
    config = _burst_config(
        args.robust_config, args.quad_psfs, args.burst_dirs[1], burst, args.scale
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ref = None
    if args.reference:
        ref = np.asarray(tifffile.imread(args.reference), dtype=np.float32)
    results: dict[str, Any] = {}
    crops = []
    for method in ("bicubic", "baseline", "robust"):
        res: FusionResult = fuse_burst(
            burst,
            scale=args.scale,
            method=method,
            use_prior=not args.no_prior,
            config=config,
        )
        entry = write_image(
            out / f"{method}.tif",
            res.image,
            as_float=args.float,
            meta={"method": method, "scale": args.scale},
        )
        entry.update({"seconds": round(res.seconds, 3), "excluded": res.excluded})
        if "psf" in res.info:
            entry["psf"] = res.info["psf"]
        if ref is not None:
            if ref.shape != res.image.shape:
                raise InputFormatError(
                    f"{args.reference}: shape={ref.shape}; allowed: "
                    f"{res.image.shape} (the output grid)"
                )
            # scores relative to the reference's own span (a 12-bit image in 16-bit
            # containers would otherwise look 24 dB better than it is)
            rng = max(float(ref.max() - ref.min()), 1e-12)
            b = 4 * args.scale
            a2 = res.image if res.image.ndim == 2 else res.image.mean(axis=2)
            r2 = ref if ref.ndim == 2 else ref.mean(axis=2)
            entry["psnr_db"] = round(psnr(r2, a2, data_range=rng, border=b), 3)
            entry["ssim"] = round(ssim(r2, a2, data_range=rng, border=b), 4)
            entry["data_range"] = rng
        results[method] = entry
        crops.append(_crop(res.image, 256))
    side = np.concatenate([np.asarray(c, np.float32) for c in crops], axis=1)
    png = save_preview(side, out / "crops.png")
    summary = {
        "burst": args.burst_dirs[1],
        "scale": args.scale,
        "methods": results,
        "crops_png": str(png),
        "crops_order": ["bicubic", "baseline", "robust"],
    }
    (out / "compare.json").write_text(json.dumps(summary, indent=1, sort_keys=True) + "\n")
    lines = [
        f"{m}: {e.get('psnr_db', '-')} dB, SSIM {e.get('ssim', '-')}, {e['seconds']} s"
        for m, e in results.items()
    ]
    emit(args, summary, "\n".join([*lines, f"crops: {png}"]))
    return 0
