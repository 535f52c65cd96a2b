"""What `make demo` shows: the simulator's truth on the fused grid, and its pictures.

`reference_image` renders the burst's scene with pixels ``scale`` times finer (what the
fused image should look like); `comparison_picture` and `burst_crops` put the same crop
of several images side by side on one tone scale and one white balance.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw

from elphel_host.preview import FONT_PX, label_font, white_balance, white_balance_gains


def reference_image(
    seed: int, carriage_mm: float, metadata: dict[str, Any], *, scale: int
) -> NDArray[np.uint16]:
    """The simulator's truth on the fused output's grid: the scene seen with S x finer pixels."""
    from elphel_camd.sensors import mt9p006 as spec
    from elphel_sim.render import Intrinsics, render_radiance
    from elphel_sim.scenarios import build

    scenario = build("default", seed=seed)
    port = scenario.ports[0]
    world = scenario.world
    world.rig.carriage_mm = carriage_mm
    lr = port.intrinsics
    cx, cy = lr.principal_point
    hr = Intrinsics(
        lr.focal_length_mm,
        lr.pixel_pitch_um / scale,
        lr.width * scale,
        lr.height * scale,
        cx * scale,
        cy * scale,
    )
    left = (spec.CLEAR_LEFT + metadata["WOI_LEFT"]) * scale
    top = (spec.CLEAR_TOP + metadata["WOI_TOP"]) * scale
    window = (left, top, metadata["WOI_WIDTH"] * scale, metadata["WOI_HEIGHT"] * scale)
    rgb = render_radiance(world, hr, world.camera_pose(port.mount), window=window)
    model = port.sensor
    dn = rgb * metadata["EXPOS"] * model.electrons_per_us * model.dn_per_e
    out: NDArray[np.uint16] = np.clip(np.rint(dn), 0, (1 << model.bits) - 1).astype(np.uint16)
    return out


def _tone(a: NDArray[np.floating], lo: float, hi: float) -> NDArray[np.uint8]:
    scaled = np.clip((np.asarray(a, np.float64) - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    out: NDArray[np.uint8] = (scaled ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    return out


def comparison_picture(
    panels: Sequence[tuple[str, NDArray[Any]]],
    path: Path,
    *,
    size: int = 96,
    zoom: int = 3,
    centre: tuple[int, int] | None = None,
) -> Path:
    """Write the same crop of several images side by side, on one tone scale, labelled.

    Parameters
    ----------
    panels
        (label, image) pairs, images 2-D or (H, W, 3) on one grid; the last one (the
        reference) sets the tone scale (0.5 and 99.5 percentiles of its crop, gamma 2.2)
        and, in colour, the white balance (`elphel_host.preview.white_balance`), so
        brightness, contrast and colour compare between panels.
    path
        The PNG to write.
    size
        Crop size in image pixels.
    zoom
        Nearest-neighbour enlargement, so that single pixels can be seen.
    centre
        (row, column) of the crop's centre; None = the image centre.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    if not panels:
        raise ValueError("panels is empty; allowed: one or more (label, image) pairs")
    shape = panels[0][1].shape
    for label, image in panels:
        if image.shape != shape:
            raise ValueError(f"panel {label!r} has shape {image.shape}; allowed: {shape}")
    h, w = shape[:2]
    cy, cx = (h // 2, w // 2) if centre is None else centre
    size = min(size, h, w)
    y0 = int(np.clip(cy - size // 2, 0, h - size))
    x0 = int(np.clip(cx - size // 2, 0, w - size))
    crops = [np.asarray(im[y0 : y0 + size, x0 : x0 + size], np.float64) for _, im in panels]
    if crops[-1].ndim == 3:  # colour: every crop balanced by the reference's gains
        gains = white_balance_gains(crops[-1])
        crops = [white_balance(c, gains=gains) for c in crops]
    lo, hi = (float(v) for v in np.percentile(crops[-1], [0.5, 99.5]))
    label_px, gap = FONT_PX + 6, 4
    side = size * zoom
    sheet = Image.new("RGB", (len(crops) * (side + gap) - gap, side + label_px), (0, 0, 0))
    draw = ImageDraw.Draw(sheet)
    for i, ((label, _), crop) in enumerate(zip(panels, crops, strict=True)):
        tile = _tone(crop, lo, hi).repeat(zoom, axis=0).repeat(zoom, axis=1)
        x = i * (side + gap)
        sheet.paste(Image.fromarray(tile).convert("RGB"), (x, label_px))
        draw.text((x + 2, 2), label, fill=(255, 255, 255), font=label_font())
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path, optimize=True)
    return path


def burst_crops(compare_dir: Path, reference: Path, path: Path) -> Path:
    """Bicubic | baseline | robust | reference crops of an `elphel mfsr compare` run."""
    import tifffile

    scores = json.loads((compare_dir / "compare.json").read_text())["methods"]
    panels: list[tuple[str, NDArray[Any]]] = []
    for method in ("bicubic", "baseline", "robust"):
        r = scores[method]
        label = f"{method} {r['psnr_db']:.2f} dB, SSIM {r['ssim']:.3f}"
        panels.append((label, tifffile.imread(compare_dir / f"{method}.tif")))
    panels.append(("reference (simulator, pitch/2)", tifffile.imread(reference)))
    return comparison_picture(panels, path)
