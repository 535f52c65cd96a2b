"""Images and RGBA textures through the inverse CLT (overlap-add, TDAC).

Every tile of every camera is taken at the position the target disparity gives it
(integer part by the window, fraction by the shifted window and phase rotation, as in
the correlation), transformed back with the unshifted window and overlap-added at stride
8: the result is each camera's image re-rendered onto the virtual centre camera's grid
at that disparity, without any resampling. Where the disparity is right the four images
agree; the texture blends them with weights that fall where one camera disagrees
(occlusion, glare) and an alpha that says how well they agree (Elphel's texture blend,
simplified from per-tile to per-pixel weights).

Bayer mosaics are demosaiced first (bilinear, per colour) so every colour is a full
image; Elphel's tile processor transforms the sparse colour planes instead and
interpolates after.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import NDArray
from scipy import ndimage

from elphel_host.tp.bayer import colour_weights, lattices
from elphel_host.tp.clt import TILE, clt_tiles, iclt_tiles, overlap_add
from elphel_host.tp.correlation import lpf_mask
from elphel_host.tp.geometry import tile_centres
from elphel_host.tp.images import QuadImages

F32 = NDArray[np.float32]


def demosaic(image: NDArray[np.floating], bayer: str | None) -> F32:
    """Colour planes ``(colours, H, W)`` (R, B, G for Bayer; one plane for mono), bilinear."""
    img = np.asarray(image, dtype=np.float32)
    if bayer is None:
        return img[None].copy()
    out = np.zeros((3, *img.shape), dtype=np.float32)
    kernel = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]], dtype=np.float32)
    for colour in range(3):
        mask = np.zeros(img.shape, dtype=np.float32)
        for lat in lattices(bayer):
            if lat.colour == colour:
                mask[lat.row :: lat.step, lat.col :: lat.step] = 1.0
        num = ndimage.convolve(img * mask, kernel, mode="mirror")
        den = ndimage.convolve(mask, kernel, mode="mirror")
        out[colour] = np.where(mask > 0, img, num / den)
    return out


def rendered_images(
    quad: QuadImages,
    disparity: NDArray[np.floating] | float,
    *,
    lpf_sigma: float = 0.0,
    chunk_tiles: int = 4096,
) -> F32:
    """Each camera's colour images on the virtual camera's grid at a disparity.

    Parameters
    ----------
    quad
        The images.
    disparity
        Scalar or ``(tiles_y, tiles_x)`` disparity per tile.
    lpf_sigma
        Optional LPF of the image: sigma of the correlation's Gaussian
        (`~elphel_host.tp.correlation.lpf_mask`; 0 = none).

    Returns
    -------
    numpy.ndarray
        ``(4, colours, H, W)`` float32; the outer 4 pixels are not reconstructed.
    """
    ty, tx = quad.tiles
    d = np.broadcast_to(np.asarray(disparity, dtype=np.float64), (ty, tx)).ravel()
    if not np.all(np.isfinite(d)):
        raise ValueError("disparity must be finite everywhere")
    cy, cx = (c.ravel() for c in tile_centres(ty, tx))
    h, w = quad.images.shape[1:]
    pad = int(np.ceil(np.abs(d).max())) + TILE
    lpf = lpf_mask(lpf_sigma).astype(np.float32)
    out = []
    for cam in range(len(quad.geometry.positions)):
        planes = demosaic(quad.images[cam], quad.bayer)
        at = quad.geometry.place_camera(cam, cx, cy, d)
        colours = []
        for plane in planes:
            padded = np.pad(plane, pad, mode="edge")
            view = np.lib.stride_tricks.sliding_window_view(padded, (TILE, TILE))
            tiles_out = np.empty((ty * tx, TILE, TILE), dtype=np.float32)
            for s in range(0, ty * tx, chunk_tiles):
                e = min(s + chunk_tiles, ty * tx)
                yy = np.clip(at.top_y[s:e] + pad, 0, view.shape[0] - 1)
                xx = np.clip(at.left_x[s:e] + pad, 0, view.shape[1] - 1)
                c = clt_tiles(view[yy, xx], shift_x=at.shift_x[s:e], shift_y=at.shift_y[s:e])
                tiles_out[s:e] = iclt_tiles(c * lpf)
            colours.append(overlap_add(tiles_out.reshape(ty, tx, TILE, TILE)))
        out.append(np.stack(colours))
    res: F32 = np.asarray(out, dtype=np.float32).reshape(4, len(colours), h, w)
    return res


def rgba_texture(
    images: F32,
    *,
    bayer: str | None,
    diff_sigma: float = 0.02,
    alpha_range: tuple[float, float] = (0.6, 0.8),
) -> F32:
    """Blend the four rendered cameras into an RGBA texture.

    Parameters
    ----------
    images
        ``(4, colours, H, W)`` from :func:`rendered_images`.
    bayer
        Pattern of the source (sets the colour weights) or None.
    diff_sigma
        Disagreement (full scale) at which a camera's weight drops to exp(-1/2).
    alpha_range
        Mean weights below the first value give alpha 0, above the second alpha 1.

    Returns
    -------
    numpy.ndarray
        ``(H, W, 4)`` float32: R, G, B (grey for mono) and alpha.
    """
    im = np.asarray(images, dtype=np.float32)
    if im.ndim != 4 or im.shape[0] != 4:
        raise ValueError(f"images must have shape (4, colours, H, W), got {im.shape}")
    if diff_sigma <= 0:
        raise ValueError(f"diff_sigma={diff_sigma}; allowed: > 0")
    wc = colour_weights(bayer).astype(np.float32)[:, None, None]
    k = 1.0 / (2.0 * diff_sigma**2)
    avg = im.mean(axis=0)
    # weights from the disagreement with the mean, then with the weighted mean again
    for _ in range(2):
        dev = (wc * (im - avg) ** 2).sum(axis=1)  # (4, H, W)
        wp = np.exp(-k * dev)
        avg = (wp[:, None] * im).sum(0) / np.maximum(wp.sum(0), 1e-12)[None]
    a0, a1 = alpha_range
    alpha = np.clip((wp.mean(axis=0) - a0) / max(a1 - a0, 1e-12), 0.0, 1.0)
    rgb = np.stack([avg[0], avg[2], avg[1]]) if bayer is not None else np.repeat(avg, 3, axis=0)
    out: F32 = np.concatenate([rgb, alpha[None]]).transpose(1, 2, 0).astype(np.float32)
    return out


def write_texture(path: str | Path, rgba: F32) -> None:
    """Write an RGBA texture from :func:`rgba_texture` as a float32 TIFF (unassociated alpha)."""
    tifffile.imwrite(path, rgba, photometric="rgb", extrasamples=["unassalpha"])
