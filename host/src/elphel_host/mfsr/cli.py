"""``elphel mfsr``: fuse burst directories; ``elphel mfsr compare``: methods side by side.

* ``elphel mfsr BURST_DIR [BURST_DIR ...] --scale S [--method robust|baseline]
  --out OUT.tif [--float] [--json]`` writes the fused TIFF (16-bit DN, or float32) and a
  PNG preview next to it. With several burst directories ``--out`` is a directory, one
  ``<burst name>.tif`` each, and the bursts run in parallel on a Dask cluster (local by
  default, or ``--scheduler tcp://host:8786``), with progress on stderr as each finishes.
* ``elphel mfsr compare BURST_DIR --scale S [--reference REF.tif] --out DIR`` runs
  bicubic, baseline and robust, scores them against the reference (PSNR, SSIM) and writes
  the three TIFFs, a ``compare.json`` and ``crops.png``: their centre crops side by side
  on one tone scale, each labelled with its method (and scores).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.burst.io import read_burst
from elphel_host.cli_common import add_json_option, emit, fusion_scale
from elphel_host.errors import InputFormatError
from elphel_host.fileio import write_atomic
from elphel_host.mfsr.fuse import FusionResult, fuse_burst
from elphel_host.mfsr.metrics import psnr, ssim
from elphel_host.mfsr.output import fused_meta, write_image
from elphel_host.mfsr.psf_spec import PsfSpec, parse_psf
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.scale import MAX_SCALE, MIN_SCALE
from elphel_host.preview import labelled_row, save_png
from elphel_host.progress import ProgressLine
from elphel_host.strict_json import report_dumps

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
        "--scale",
        type=fusion_scale,
        required=True,
        metavar="S",
        help=f"integer {MIN_SCALE}..{MAX_SCALE}",
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


def psf_choice(text: str | None) -> PsfSpec | QuadPsfs:
    """``--psf``: a :data:`~elphel_host.mfsr.psf_spec.PsfSpec`, or a quad's PSFs.

    ``quad=DIR[,camera=N]`` gives the PSFs recovered from a quad's kernel file, drawn per
    burst under its window (:func:`robust_config`); any other value is parsed by
    :func:`~elphel_host.mfsr.psf_spec.parse_psf`.
    """
    text = "auto" if text is None else text
    try:
        if not text.strip().startswith("quad="):
            return parse_psf(text)
    except ValueError as e:
        raise InputFormatError(str(e)) from e
    from elphel_host.mfsr.psf_tp import quad_psfs  # SciPy's optimiser: only when asked for

    where, _, rest = text.strip()[len("quad=") :].partition(",")
    camera = rest[len("camera=") :] if rest.startswith("camera=") else None
    if not where or (rest and (camera is None or not camera.isdigit())):
        raise InputFormatError(f"--psf {text!r}; allowed: quad=QUAD_DIR or quad=QUAD_DIR,camera=N")
    return quad_psfs(where, int(camera or 0))


def robust_config(
    choice: PsfSpec | QuadPsfs, burst_dir: str, burst: Burst, scale: int
) -> RobustConfig:
    """The robust method's options for one burst: a quad's PSFs drawn under its window."""
    if isinstance(choice, PsfSpec):
        return RobustConfig(psf=choice)
    from elphel_host.mfsr.psf_tp import burst_psf

    return RobustConfig(psf=burst_psf(choice, burst_dir, burst, scale))


def _fuse_one(
    burst_dir: str,
    scale: int,
    method: str,
    out: str,
    as_float: bool,
    psf: PsfSpec | QuadPsfs,
    use_prior: bool,
) -> dict[str, Any]:
    burst = read_burst(burst_dir)
    res = fuse_burst(
        burst,
        scale=scale,
        method=method,
        use_prior=use_prior,
        config=robust_config(psf, burst_dir, burst, scale),
    )
    meta = fused_meta(method=method, scale=scale, burst=burst_dir, bayer=burst.bayer)
    written = write_image(Path(out), res.image, as_float=as_float, meta=meta)
    return {"burst": str(burst_dir), **written, **res.report()}


def run(args: argparse.Namespace) -> int:
    args.psf_choice = psf_choice(args.psf)
    if args.burst_dirs[0] == "compare":
        return run_compare(args)
    dirs = args.burst_dirs
    if len(dirs) == 1:
        line = ProgressLine()
        try:
            with line.ticking(f"mfsr: fusing {dirs[0]} ({args.method} x{args.scale})"):
                result = _fuse_one(
                    dirs[0],
                    args.scale,
                    args.method,
                    args.out,
                    args.float,
                    args.psf_choice,
                    not args.no_prior,
                )
        finally:
            line.end()
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
                    args.psf_choice,
                    not args.no_prior,
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


def _scores(
    ref: NDArray[np.float32], image: NDArray[np.float32], scale: int, name: str
) -> dict[str, float]:
    """PSNR and SSIM of ``image`` against the reference ``ref`` (luminance of RGB)."""
    if ref.shape != image.shape:
        raise InputFormatError(
            f"{name}: shape={ref.shape}; allowed: {image.shape} (the output grid)"
        )
    # scores relative to the reference's own span (a 12-bit image in 16-bit containers
    # would otherwise look 24 dB better than it is)
    rng = max(float(ref.max() - ref.min()), 1e-12)
    b = 4 * scale
    a2 = image if image.ndim == 2 else image.mean(axis=2)
    r2 = ref if ref.ndim == 2 else ref.mean(axis=2)
    return {
        "psnr_db": round(psnr(r2, a2, data_range=rng, border=b), 3),
        "ssim": round(ssim(r2, a2, data_range=rng, border=b), 4),
        "data_range": rng,
    }


def crop_label(method: str, entry: dict[str, Any]) -> str:
    """A crop's label in crops.png: the method, with its scores when there is a reference."""
    if "psnr_db" not in entry:
        return method
    return f"{method} {entry['psnr_db']:.2f} dB, SSIM {entry['ssim']:.3f}"


def run_compare(args: argparse.Namespace) -> int:
    if len(args.burst_dirs) != 2:
        raise InputFormatError(f"compare takes one BURST_DIR, got {args.burst_dirs[1:]}")
    burst = read_burst(args.burst_dirs[1])
    config = robust_config(args.psf_choice, args.burst_dirs[1], burst, args.scale)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ref = None
    if args.reference:
        ref = np.asarray(tifffile.imread(args.reference), dtype=np.float32)
    results: dict[str, Any] = {}
    crops: list[tuple[str, NDArray[np.float32]]] = []
    line = ProgressLine()
    for i, method in enumerate(("bicubic", "baseline", "robust"), start=1):
        with line.ticking(f"mfsr compare: {i}/3 {method} x{args.scale}"):
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
            entry.update(_scores(ref, res.image, args.scale, args.reference))
        results[method] = entry
        crops.append((crop_label(method, entry), _crop(res.image, 256)))
    line.end()
    png = save_png(labelled_row(crops), out / "crops.png")
    summary = {
        "burst": args.burst_dirs[1],
        "scale": args.scale,
        "methods": results,
        "crops_png": str(png),
        "crops_order": ["bicubic", "baseline", "robust"],
    }
    # An image identical to the reference has an infinite PSNR: null, named in "non_finite".
    text = report_dumps(summary, indent=1, sort_keys=True)
    write_atomic(out / "compare.json", (text + "\n").encode())
    lines = [
        f"{m}: {e.get('psnr_db', '-')} dB, SSIM {e.get('ssim', '-')}, {e['seconds']} s"
        for m, e in results.items()
    ]
    emit(args, summary, "\n".join([*lines, f"crops: {png}"]))
    return 0
