"""Pictures of particle rollouts: frames coloured by speed (the paper's figure 1 style), side-by-side panels
(figure 8), strips of frames (figure 1), single-frame PNGs and GIF/MP4 animations.

Particles are rasterised directly into numpy images (a few ms per frame, so a 600-frame animation takes
seconds rather than the minutes a matplotlib scatter per frame would); PIL writes the panel titles and imageio
(with the ffmpeg it bundles) writes GIF and MP4.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import imageio.v2
import imageio.v3 as iio
import numpy as np
from matplotlib import colormaps
from PIL import Image, ImageDraw

from gnsx.constants import KINEMATIC_PARTICLE_ID

BACKGROUND = np.array([12, 14, 28], np.uint8)
GREY = np.array([150, 150, 150], np.uint8)
#: Slow particles dark blue, fast ones white (the paper's figure 1 colouring).
SPEED_COLORMAP = colormaps["Blues_r"]


def _disc_offsets(radius_px: int) -> np.ndarray:
    r = np.arange(-radius_px, radius_px + 1)
    dy, dx = np.meshgrid(r, r, indexing="ij")
    keep = dx**2 + dy**2 <= radius_px**2 + radius_px
    return np.stack([dy[keep], dx[keep]], axis=1)  # [K, 2]


def render_frame(
    position: np.ndarray,
    particle_type: np.ndarray,
    speed: np.ndarray,
    bounds: np.ndarray,
    size: int = 256,
    speed_scale: float = 1.0,
    dot_px: int = 1,
) -> np.ndarray:
    """One frame as an RGB image.

    Args:
        position: ``[N, 2]`` positions (data units).
        particle_type: ``[N]``.
        speed: ``[N]`` per-frame displacement magnitude (data units per frame).
        bounds: ``[2, 2]`` ``[[xmin, xmax], [ymin, ymax]]``; drawn as grey walls; the image shows the unit
            square around them (WaterRamps' domain is [0, 1]^2 with walls at 0.1 and 0.9).
        speed_scale: speed mapped to the brightest colour.
    Returns:
        ``[size, size, 3]`` uint8, y up.
    """
    image = np.empty((size, size, 3), np.uint8)
    image[:] = BACKGROUND
    # Viewport: the bounds plus a margin of 1/8 of their size on each side ([0.1, 0.9] -> [0, 1]), square.
    span = float(np.max(bounds[:, 1] - bounds[:, 0]))
    lo = bounds[:, 0] - span / 8
    extent = span * 1.25

    def to_pixels(p: np.ndarray) -> np.ndarray:
        xy = (p - lo) / extent * (size - 1)
        return np.stack([size - 1 - np.round(xy[..., 1]), np.round(xy[..., 0])], axis=-1).astype(np.int64)

    # Walls: the rectangle of the bounds.
    (r0, c0), (r1, c1) = to_pixels(np.array([[bounds[0, 0], bounds[1, 0]], [bounds[0, 1], bounds[1, 1]]]))
    r0, r1 = sorted((int(r0), int(r1)))
    c0, c1 = sorted((int(c0), int(c1)))
    image[r0 : r1 + 1, [c0, c1]] = GREY
    image[[r0, r1], c0 : c1 + 1] = GREY

    colors = (SPEED_COLORMAP(np.clip(speed / max(speed_scale, 1e-12), 0.0, 1.0))[:, :3] * 255).astype(
        np.uint8
    )
    colors[particle_type == KINEMATIC_PARTICLE_ID] = GREY
    pixels = to_pixels(position)
    offsets = _disc_offsets(dot_px)
    stamped = (pixels[:, None, :] + offsets[None]).reshape(-1, 2)
    inside = (stamped >= 0).all(axis=1) & (stamped < size).all(axis=1)
    # Draw slow particles first so fast (bright) ones stay visible on top (numpy keeps the last write).
    stamped_colors = np.repeat(colors, len(offsets), axis=0)
    by_speed = np.argsort(speed, kind="stable")
    index = (by_speed[:, None] * len(offsets) + np.arange(len(offsets))[None]).ravel()
    keep = index[inside[index]]
    image[stamped[keep, 0], stamped[keep, 1]] = stamped_colors[keep]
    return image


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


def render_rollouts(
    rollouts: Sequence[np.ndarray],
    particle_type: np.ndarray,
    bounds: np.ndarray,
    titles: Sequence[str] | None = None,
    size: int = 256,
    frame_stride: int = 1,
    frames: Sequence[int] | None = None,
) -> np.ndarray:
    """Side-by-side panels of several rollouts of the same scene, one image per frame (the paper's figure 8).

    Args:
        rollouts: each ``[T, N, 2]`` (the same T and N), e.g. ground truth and predictions.
        titles: one per panel (e.g. "ground truth", "simplified GNS").
        frame_stride: keep every ``frame_stride``-th frame.
        frames: the frame indices to render (overrides ``frame_stride``).
    Returns:
        ``[T', size, size * len(rollouts), 3]`` uint8 frames.
    """
    bounds = np.asarray(bounds, np.float64)
    all_speeds = [speeds(np.asarray(r)) for r in rollouts]
    # One colour scale for every panel, from the first rollout (ground truth when given first).
    scale = colour_scale(all_speeds[0], particle_type)
    picks = range(0, rollouts[0].shape[0], frame_stride) if frames is None else frames
    images = []
    for t in picks:
        panels = []
        for i, (r, s) in enumerate(zip(rollouts, all_speeds)):
            panel = render_frame(np.asarray(r[t]), particle_type, s[t], bounds, size, speed_scale=scale)
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
) -> Path:
    """The paper's figure 1 strip as a PNG: frames 0, every, 2*every, ... (at most ``count``) in a row, one
    row per rollout (ground truth | original | simplified as rows gives a figure-8 style comparison).

    Args:
        rollouts: each ``[T, N, 2]`` (same T, N).
        every, count: frame step and the number of frames per row (figure 1: 7 frames every 100).
    Returns:
        ``path``.
    """
    num_frames = rollouts[0].shape[0]
    picks = list(range(0, num_frames, every))[:count]
    bounds = np.asarray(bounds, np.float64)
    # One colour scale for all rows, from the first rollout, as in the animations.
    scale = colour_scale(speeds(np.asarray(rollouts[0])), particle_type)
    rows = []
    for i, r in enumerate(rollouts):
        s = speeds(np.asarray(r))
        cells = []
        for t in picks:
            cell = render_frame(np.asarray(r[t]), particle_type, s[t], bounds, size, speed_scale=scale)
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
        position, particle_type, speed, np.asarray(bounds, np.float64), size, speed_scale=scale
    )
    if title:
        image = _title(image, title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, image)
    return path
