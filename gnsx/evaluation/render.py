"""Pictures of particle rollouts: frames coloured by speed (the paper's figure 1 style), side-by-side panels
(figure 8), strips of frames (figure 1), single-frame PNGs and GIF/MP4 animations.

Particles are drawn as overlapping discs sized from the particle spacing, so a block or a pool of water reads
as a body of water (see :func:`render_frame`). They are rasterised directly into numpy images (a few ms per
frame, so a 600-frame animation takes seconds rather than the minutes a matplotlib scatter per frame would);
PIL writes the panel titles and imageio (with the ffmpeg it bundles) writes GIF and MP4.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import imageio.v2
import imageio.v3 as iio
import numpy as np
from matplotlib import colormaps
from PIL import Image, ImageDraw

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.evaluation import metrics

BACKGROUND = np.array([12, 14, 28], np.uint8)
GREY = np.array([150, 150, 150], np.uint8)
#: Slow particles dark blue, fast ones white (the paper's figure 1 colouring).
SPEED_COLORMAP = colormaps["Blues_r"]


#: Disc radius as a multiple of half the particle spacing (the disc diameter is 1.7 spacings). At 1 the
#: discs of a square lattice just touch and leave 21% of a pool as background between them; MPM water is
#: worse (jittered, and it clumps into pairs and chains as it flows). Measured at 256 px on MPM rollouts
#: of the ``small`` and ``waterramps`` presets, the share of background pixels inside the water: 5-8% on
#: the first frame and 14-20% later at 1.4; 0.2% first and 4-8% later at 1.7 (1.8: 1-4%, with fatter
#: spray). At 1.7 a block or a pool reads as one body of water with a faint texture of specks.
DISC_OVERLAP = 1.7
#: Static particles' discs as a multiple of half *their* spacing (at most the water's radius): neighbours
#: along a ramp overlap, so a ramp reads as a thin continuous line rather than a row of beads.
STATIC_DISC_OVERLAP = 1.3
#: The largest automatic disc radius as a fraction of the frame: sparse particles (a few random points, a
#: spray) stay dots instead of blobs.
MAX_DISC_FRACTION = 1 / 40
#: Pixels per output pixel (per axis) rasterised before averaging down: anti-aliased disc edges.
SUPERSAMPLE = 2


def _disc_offsets(radius: float) -> np.ndarray:
    """``[K, 2]`` (row, column) offsets of the pixels whose centres lie within ``radius`` pixels (>= 1)."""
    reach = int(np.floor(radius))
    r = np.arange(-reach, reach + 1)
    dy, dx = np.meshgrid(r, r, indexing="ij")
    keep = dx**2 + dy**2 <= max(radius, 0.0) ** 2
    return np.stack([dy[keep], dx[keep]], axis=1)


def _viewport(bounds: np.ndarray, size: int) -> tuple[np.ndarray, float]:
    """The bounds plus a margin of 1/8 of their size on each side ([0.1, 0.9] -> [0, 1]), square: the lower
    corner (data units) and the output pixels per data unit."""
    span = float(np.max(bounds[:, 1] - bounds[:, 0]))
    return bounds[:, 0] - span / 8, (size - 1) / (span * 1.25)


def particle_spacing(position: np.ndarray, particle_type: np.ndarray) -> tuple[float | None, float | None]:
    """Typical distance between neighbouring particles (data units): ``(dynamic, static)``, each
    :func:`gnsx.model.neighbors.particle_spacing` of that kind of particle among its own kind (4 neighbours for
    water, whose nearest-neighbour distance alone would size discs that leave gaps; 1 for the static
    particles on ramps, the spacing along the line). None where fewer than 2 have finite positions.
    """
    position = np.asarray(position, np.float64)
    static = np.asarray(particle_type) == KINEMATIC_PARTICLE_ID
    out = []
    for points, neighbours in ((position[~static], 4), (position[static], 1)):
        value = metrics.particle_spacing(points, neighbours)
        out.append(value if value > 0 else None)  # NaN (too few particles) is not > 0
    return out[0], out[1]


def disc_radii(
    spacing: tuple[float | None, float | None], bounds: np.ndarray, size: int
) -> tuple[float, float]:
    """Disc radii in output pixels, ``(dynamic, static)``, for particles ``spacing`` apart (see
    :func:`particle_spacing`) in a ``size``-pixel frame of ``bounds``.

    Dynamic (water) particles: ``DISC_OVERLAP`` times half their spacing, so the discs of neighbours overlap
    and a resting pool is painted solid; at least 1 pixel, at most ``MAX_DISC_FRACTION`` of the frame.
    Static (ramp) particles: ``STATIC_DISC_OVERLAP`` times half their spacing, at least 1 pixel and at most
    the water's radius, so ramps read as thin continuous lines.
    """
    _, px_per_unit = _viewport(np.asarray(bounds, np.float64), size)
    dynamic, static = spacing
    largest = max(1.0, MAX_DISC_FRACTION * size)
    dot = 1.0 if dynamic is None else float(np.clip(0.5 * DISC_OVERLAP * dynamic * px_per_unit, 1.0, largest))
    if static is None:
        return dot, dot
    return dot, float(np.clip(0.5 * STATIC_DISC_OVERLAP * static * px_per_unit, 1.0, dot))


def render_frame(
    position: np.ndarray,
    particle_type: np.ndarray,
    speed: np.ndarray,
    bounds: np.ndarray,
    size: int = 256,
    speed_scale: float = 1.0,
    dot_px: float | None = None,
    static_dot_px: float | None = None,
    supersample: int = SUPERSAMPLE,
) -> np.ndarray:
    """One frame as an RGB image.

    Particles are discs ``DISC_OVERLAP`` (1.7) particle spacings wide, so the discs of neighbours overlap
    and a block or a pool of water is painted as one body (fixed 3-pixel dots, at the 2.3-4 pixel spacing of
    the presets' water in a 256-pixel frame, left it a cloud of dots). By default the radius comes from the
    data, :func:`particle_spacing` of this frame through :func:`disc_radii`; callers drawing many frames of
    one scene (:func:`render_rollouts`, :func:`save_strip`) measure the spacing once, on the first frame, and
    pass the radii, so the discs keep their size while the water moves and splashes. Static particles get
    smaller discs from their own spacing and are drawn last, on top of the water, so ramps read as lines.
    Particles are rasterised at ``supersample`` times the size and averaged down, which anti-aliases the
    disc edges; the walls stay one crisp grey pixel wide. Non-finite positions (a diverged rollout) are
    not drawn.

    Args:
        position: ``[N, 2]`` positions (data units).
        particle_type: ``[N]``.
        speed: ``[N]`` per-frame displacement magnitude (data units per frame).
        bounds: ``[2, 2]`` ``[[xmin, xmax], [ymin, ymax]]``; drawn as grey walls; the image shows the unit
            square around them (WaterRamps' domain is [0, 1]^2 with walls at 0.1 and 0.9).
        speed_scale: speed mapped to the brightest colour.
        dot_px: disc radius of dynamic (water) particles in output pixels; None: from the data.
        static_dot_px: disc radius of static particles; None: from the data (``dot_px`` when that is given).
        supersample: rasterise at this many pixels per output pixel per axis (1: no anti-aliasing).
    Returns:
        ``[size, size, 3]`` uint8, y up.
    """
    position = np.asarray(position)
    particle_type = np.asarray(particle_type)
    speed = np.asarray(speed)
    bounds = np.asarray(bounds, np.float64)
    if dot_px is None:
        dot_px, auto_static = disc_radii(particle_spacing(position, particle_type), bounds, size)
        static_dot_px = auto_static if static_dot_px is None else static_dot_px
    elif static_dot_px is None:
        static_dot_px = dot_px
    f = max(1, int(supersample))
    big = size * f
    lo, px_per_unit = _viewport(bounds, size)
    radii = (dot_px * f, static_dot_px * f)
    # The canvas: one uint64 per supersampled pixel, 16 bits per channel (room to sum f^2 of them), with a
    # margin wider than any disc so stamping needs no bounds checks (particles further out are clamped
    # into the margin and vanish with it).
    reach = int(np.floor(max(radii)))
    pad = reach + 1
    margin = pad + reach
    width = big + 2 * margin
    canvas = np.full(width * width, _pack(BACKGROUND), np.uint64)
    view = canvas.reshape(width, width)[margin : margin + big, margin : margin + big]
    # Walls: the rectangle of the bounds, one output pixel wide.
    (c0, c1), (y0, y1) = np.round((bounds - lo[:, None]) * px_per_unit).astype(int)
    r0, r1 = size - 1 - y1, size - 1 - y0
    for r in (r0, r1):
        view[r * f : (r + 1) * f, c0 * f : (c1 + 1) * f] = _pack(GREY)
    for c in (c0, c1):
        view[r0 * f : (r1 + 1) * f, c * f : (c + 1) * f] = _pack(GREY)

    colors = (SPEED_COLORMAP(np.clip(speed / max(speed_scale, 1e-12), 0.0, 1.0))[:, :3] * 255).astype(
        np.uint8
    )
    static = particle_type == KINEMATIC_PARTICLE_ID
    colors[static] = GREY
    colors = _pack(colors)
    # Supersampled (column, row) of every particle; output pixel i covers supersampled pixels i*f .. i*f+f-1.
    xy = (position - lo) * px_per_unit * f + (f - 1) / 2
    xy[~np.isfinite(xy).all(axis=1)] = -1e9  # clamped into the margin below, so not drawn
    col = np.clip(np.round(xy[:, 0]), -pad, big - 1 + pad).astype(np.int64) + margin
    row = np.clip(np.round(big - 1 - xy[:, 1]), -pad, big - 1 + pad).astype(np.int64) + margin
    centre = row * width + col
    # Slow particles first so fast (bright) ones stay visible on top (numpy keeps the last write); static
    # particles last, on top of the water, so ramps stay lines.
    order = np.lexsort((speed, static))
    for group, radius in ((order[~static[order]], radii[0]), (order[static[order]], radii[1])):
        offsets = _disc_offsets(radius)
        offsets = offsets[:, 0] * width + offsets[:, 1]
        canvas[(centre[group, None] + offsets[None]).ravel()] = np.repeat(colors[group], len(offsets))
    total = view[0::f, 0::f].copy()
    for i in range(f):
        for j in range(f):
            if i or j:
                total += view[i::f, j::f]
    channels = total.astype("<u8", copy=False).view("<u2").reshape(size, size, 4)[..., :3]
    return ((channels + np.uint16(f * f // 2)) // np.uint16(f * f)).astype(np.uint8)


def _pack(rgb: np.ndarray) -> np.ndarray:
    """``[..., 3]`` uint8 colours as ``[...]`` uint64, one 16-bit field per channel."""
    rgb = np.asarray(rgb).astype(np.uint64)
    return rgb[..., 0] | (rgb[..., 1] << np.uint64(16)) | (rgb[..., 2] << np.uint64(32))


def speeds(positions: np.ndarray) -> np.ndarray:
    """``[T, N]`` per-frame displacement magnitude of ``[T, N, D]`` positions (0 for the first frame)."""
    v = np.zeros(positions.shape[:2], np.float32)
    v[1:] = np.linalg.norm(np.diff(positions, axis=0), axis=-1)
    return v


def _title(image: np.ndarray, text: str) -> np.ndarray:
    canvas = Image.fromarray(image)
    ImageDraw.Draw(canvas).text((6, 4), text, fill=(230, 230, 230))
    return np.asarray(canvas)


def colour_scale(speed: np.ndarray, particle_type: np.ndarray) -> float:
    """The speed mapped to the brightest colour: the 99th percentile over dynamic particles (1 if none move).

    Args:
        speed: ``[..., N]`` speeds (data units per frame).
        particle_type: ``[N]``.
    """
    moving = np.asarray(speed)[..., np.asarray(particle_type) != KINEMATIC_PARTICLE_ID]
    scale = float(np.percentile(moving, 99)) if moving.size else 0.0
    return scale if scale > 0 else 1.0


def _radii(
    rollouts: Sequence[np.ndarray],
    particle_type: np.ndarray,
    bounds: np.ndarray,
    size: int,
    dot_px: float | None,
) -> tuple[float, float | None]:
    """``(dot_px, static_dot_px)`` for :func:`render_frame`: measured once, on the first rollout's first
    frame, unless ``dot_px`` is given."""
    if dot_px is not None:
        return dot_px, None
    return disc_radii(particle_spacing(np.asarray(rollouts[0][0]), particle_type), bounds, size)


def render_rollouts(
    rollouts: Sequence[np.ndarray],
    particle_type: np.ndarray,
    bounds: np.ndarray,
    titles: Sequence[str] | None = None,
    size: int = 256,
    frame_stride: int = 1,
    frames: Sequence[int] | None = None,
    dot_px: float | None = None,
) -> np.ndarray:
    """Side-by-side panels of several rollouts of the same scene, one image per frame (the paper's figure 8).

    Args:
        rollouts: each ``[T, N, 2]`` (the same T and N), e.g. ground truth and predictions.
        titles: one per panel (e.g. "ground truth", "simplified GNS").
        frame_stride: keep every ``frame_stride``-th frame.
        frames: the frame indices to render (overrides ``frame_stride``).
        dot_px: particle disc radius in pixels; None: from the particle spacing of the first rollout's first
            frame, measured once for every frame and panel (see :func:`render_frame`).
    Returns:
        ``[T', size, size * len(rollouts), 3]`` uint8 frames.
    """
    bounds = np.asarray(bounds, np.float64)
    all_speeds = [speeds(np.asarray(r)) for r in rollouts]
    # One colour scale for every panel, from the first rollout (ground truth when given first).
    scale = colour_scale(all_speeds[0], particle_type)
    radii = _radii(rollouts, particle_type, bounds, size, dot_px)
    picks = range(0, rollouts[0].shape[0], frame_stride) if frames is None else frames
    images = []
    for t in picks:
        panels = []
        for i, (r, s) in enumerate(zip(rollouts, all_speeds)):
            panel = render_frame(np.asarray(r[t]), particle_type, s[t], bounds, size, scale, *radii)
            label = f"{titles[i]}  frame {t}" if titles else f"frame {t}"
            panels.append(_title(panel, label))
        images.append(np.concatenate(panels, axis=1))
    return np.stack(images)


def save_animation(frames: np.ndarray, path: str | Path, fps: int = 30) -> Path:
    """Write ``[T, H, W, 3]`` uint8 frames as GIF or MP4 (by the suffix of ``path``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".mp4":
        # ffmpeg from imageio-ffmpeg; macro_block_size=1 keeps our frame size as it is.
        imageio.v2.mimwrite(path, list(frames), fps=fps, codec="libx264", macro_block_size=1)
    elif path.suffix == ".gif":
        iio.imwrite(path, frames, duration=1000 / fps, loop=0)
    else:
        raise ValueError(f"{path}: unsupported animation format (use .gif or .mp4)")
    return path


def save_strip(
    rollouts: Sequence[np.ndarray],
    particle_type: np.ndarray,
    bounds: np.ndarray,
    path: str | Path,
    titles: Sequence[str] | None = None,
    every: int = 100,
    count: int = 7,
    size: int = 192,
    dot_px: float | None = None,
) -> Path:
    """The paper's figure 1 strip as a PNG: frames 0, every, 2*every, ... (at most ``count``) in a row, one
    row per rollout (ground truth | original | simplified as rows gives a figure-8 style comparison).

    Args:
        rollouts: each ``[T, N, 2]`` (same T, N).
        every, count: frame step and the number of frames per row (figure 1: 7 frames every 100).
        dot_px: particle disc radius in pixels; None: from the first rollout's first frame, as
            :func:`render_rollouts`.
    Returns:
        ``path``.
    """
    num_frames = rollouts[0].shape[0]
    picks = list(range(0, num_frames, every))[:count]
    bounds = np.asarray(bounds, np.float64)
    # One colour scale for all rows, from the first rollout, as in the animations.
    scale = colour_scale(speeds(np.asarray(rollouts[0])), particle_type)
    radii = _radii(rollouts, particle_type, bounds, size, dot_px)
    rows = []
    for i, r in enumerate(rollouts):
        s = speeds(np.asarray(r))
        cells = []
        for t in picks:
            cell = render_frame(np.asarray(r[t]), particle_type, s[t], bounds, size, scale, *radii)
            cells.append(_title(cell, f"{titles[i]}  frame {t}" if titles else f"frame {t}"))
        rows.append(np.concatenate(cells, axis=1))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.concatenate(rows, axis=0))
    return path


def save_frame(
    position: np.ndarray,
    particle_type: np.ndarray,
    bounds: np.ndarray,
    path: str | Path,
    speed: np.ndarray | None = None,
    size: int = 256,
    title: str | None = None,
    speed_scale: float | None = None,
    dot_px: float | None = None,
) -> Path:
    """One frame of a rollout as a PNG (e.g. a cell of a sweep report's grid).

    Args:
        position: ``[N, 2]`` positions (data units).
        particle_type: ``[N]``.
        bounds: ``[2, 2]`` walls.
        path: the ``.png`` to write.
        speed: ``[N]`` per-frame displacement magnitudes for the colours (e.g. ``speeds(rollout)[t]``); None
            draws every moving particle in one mid colour.
        title: written in the top-left corner.
        speed_scale: the speed of the brightest colour (None: :func:`colour_scale` of ``speed``).
        dot_px: particle disc radius in pixels; None: from this frame's particle spacing.
    Returns:
        ``path``.
    """
    position = np.asarray(position)
    particle_type = np.asarray(particle_type)
    if speed is None:
        speed, scale = np.full(len(position), 0.5), 1.0
    else:
        speed = np.asarray(speed)
        scale = colour_scale(speed, particle_type) if speed_scale is None else speed_scale
    image = render_frame(
        position, particle_type, speed, np.asarray(bounds, np.float64), size, scale, dot_px=dot_px
    )
    if title:
        image = _title(image, title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, image)
    return path
